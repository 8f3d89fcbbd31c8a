"""Tests of odocal.preprocess."""
