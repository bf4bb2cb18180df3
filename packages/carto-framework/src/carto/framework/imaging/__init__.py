"""Images on the ground: ortho grids, orthorectification, raw images prepared for matching."""
