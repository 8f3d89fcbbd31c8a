"""Tests of odocal.estimators."""
