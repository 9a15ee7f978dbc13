"""Motor description files: a motor's name, limits, loss model and thermal prior, as a user writes them."""
