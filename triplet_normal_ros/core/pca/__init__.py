"""PCA of a neighbourhood: frames and sign conventions, the closed-form 3 × 3 eigen solver, and pool PCA (torch, and
its compiled twins in `<stem>_numba`)."""
