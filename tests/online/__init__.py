"""Tests of odocal.online."""
