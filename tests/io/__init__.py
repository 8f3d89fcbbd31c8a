"""Tests of odocal.io."""
