"""Rod model, linearization, sampled-loop gain design and C header generation (see README)."""
