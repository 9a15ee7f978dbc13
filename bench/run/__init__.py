"""A bench run's wing: what a run needs before it starts (`inputs`), the target process it starts and stops
(`target`), the run itself with the target on the bus (`execute`), and the cleanup of what a killed run left
behind (`leftovers`)."""
