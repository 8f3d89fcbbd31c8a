"""Tests of odocal.cli."""
