"""Dataset readers and the Episode type."""
