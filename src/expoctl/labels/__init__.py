"""Self-supervised training labels: the targets M_feat, M_match, M_hybrid (`targets`), the training samples built
from them (`samples`) and the label statistics report (`report`).
"""

from expoctl.labels.report import compute_label_stats, flat_metrics, render_markdown
from expoctl.labels.samples import SampleConfig, build_samples, summarise_samples
from expoctl.labels.targets import LabelConfig, compute_labels

__all__ = ["LabelConfig", "SampleConfig", "build_samples", "compute_label_stats", "compute_labels", "flat_metrics",
           "render_markdown", "summarise_samples"]
