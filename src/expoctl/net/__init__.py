"""The controller network: its input preprocessing, the model, the training data, training, checkpoints and the
open-loop camera-follow probe."""
