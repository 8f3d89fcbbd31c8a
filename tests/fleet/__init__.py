"""Tests of odocal.fleet."""
