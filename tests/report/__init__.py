"""Tests of odocal.report."""
