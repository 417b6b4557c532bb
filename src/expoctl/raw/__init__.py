"""The raw recording format: dual-camera sequences on disk (`format`; a real rig or the simulator writes them), their
validation (`validate`, and the `expoctl validate` command in `validate_cli`) and their ingestion into the frames
table and the training image store (`ingest`; its entry point `ingest.ingest` keeps its module's name, so it is not
re-exported here).
"""

from expoctl.raw.format import SequenceWriter, decode_8bit_image, find_sequences, read_image_rgb
from expoctl.raw.ingest import IngestConfig
from expoctl.raw.validate import check_sequence, validate_raw_dir

__all__ = ["IngestConfig", "SequenceWriter", "check_sequence", "decode_8bit_image", "find_sequences", "read_image_rgb",
           "validate_raw_dir"]
