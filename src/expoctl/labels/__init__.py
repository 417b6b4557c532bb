"""Self-supervised training labels: the targets (M_feat, M_match, M_hybrid), the training samples built from them and
the label statistics report."""
