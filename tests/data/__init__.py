"""Tests of odocal.data."""
