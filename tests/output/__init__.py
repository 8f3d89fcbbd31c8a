"""Tests of odocal.output."""
