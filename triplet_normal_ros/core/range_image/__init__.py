"""An organized range image's own machinery: the grid check, the moment image with its window PCA, hybrid's survey
and cue, and the lattice. Each torch module has its compiled twin in `<stem>_numba`."""
