"""Controller design: gain policy, delay margin, the input-model fit."""
