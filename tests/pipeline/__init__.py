"""Tests of odocal.pipeline."""
