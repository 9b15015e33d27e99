"""Hydra launcher that runs each sweep job as a Ray task, on a local Ray cluster or an existing one."""

INSTALL_LINE = "pip install -c constraints.txt -e '.[cluster]'  (or: make install-cluster)"
