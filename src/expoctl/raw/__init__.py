"""The raw recording format: dual-camera sequences on disk, their validation and their ingestion."""
