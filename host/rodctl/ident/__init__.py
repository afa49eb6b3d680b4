"""System identification: excitation experiments on the board and an output-error fit against the
project's C plant (`rodctl identify`)."""
