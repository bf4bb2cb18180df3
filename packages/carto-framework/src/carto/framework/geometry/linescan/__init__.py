"""The rigorous line scanner: the model (:mod:`.scanner`, :class:`.scanner.LineScanner`),
ground-to-image by a tabulated solver (:mod:`.solver`), rays and their intersection with a
DEM (:mod:`.raycast`), line timing (:mod:`.timing`) and staggered detector arrays
(:mod:`.stagger`)."""
