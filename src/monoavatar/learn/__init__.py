"""Learned parts (Papers D and E): networks, losses, weights, training loop; their data comes
from synth."""
