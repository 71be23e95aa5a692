"""Buildings: footprints by example (thesis ch. 5), attributes by example, Scharl's
library buildings, part-based buildings on the sequence engine (thesis ch. 3, 6)."""
