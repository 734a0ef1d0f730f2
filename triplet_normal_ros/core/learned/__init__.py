"""The network's side: the model, checkpoints and their tensor files, patches and their scale fits (torch, and their
compiled twins in `<stem>_numba`)."""
