"""Data: the fixed train/eval split, training windows and normalisation statistics."""
