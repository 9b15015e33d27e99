"""RDD: retrieval-based demonstration decomposition (Yan et al., NeurIPS 2025)."""
