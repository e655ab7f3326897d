"""Online validation: streams, sample alignment, whole-period windows, the alarm and the facade."""
