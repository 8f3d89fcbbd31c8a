"""From raw streams to a drive: alignment, reference-pose fusion and sideslip (METHOD 7)."""
