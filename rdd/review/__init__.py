"""``python -m rdd review``: a local web page where a person checks and fixes decompositions.

:mod:`.session` holds what the page shows and edits (no web framework), :mod:`.app` its HTTP face
(FastAPI, the ``serve`` extra), ``static/`` the page itself (plain HTML and JavaScript, no build step).
"""
