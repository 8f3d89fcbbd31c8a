"""Tests of odocal.checks."""
