"""A labelled corpus of rendered notes and gestures (`bowsynth dataset`), in the layout Hugging Face datasets loads."""
