"""Tests of odocal.sim."""
