"""Tests of odocal.model."""
