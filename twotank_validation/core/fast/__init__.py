"""The fast path: the per-bin problem solved by dual ascent over small matrices."""
