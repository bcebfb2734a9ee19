"""The data pipeline: dataset readers, filters, deduplication, captions, clip export, engines."""
