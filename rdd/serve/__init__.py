"""``python -m rdd serve``: decomposition over HTTP in the official RDD server's request and answer
shapes (``rdd.serve.service``: the checks and the work; ``rdd.serve.app``: the FastAPI routes)."""
