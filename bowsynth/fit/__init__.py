"""Sound matching: the bow (and f0) that make the operator sound like a target recording (`bowsynth fit`)."""
