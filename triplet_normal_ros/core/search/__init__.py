"""Neighbour searches behind one `pools.open_search`: the KD-tree (compiled), cell lists (voxels) and the pixel grid of
an organized range image."""
