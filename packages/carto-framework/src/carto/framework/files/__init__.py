"""Files the framework reads and writes whole: atomic outputs, JSON documents, point tables."""
