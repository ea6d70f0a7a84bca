"""Audio front end: STFT/spectrograms and separation metrics."""
