"""modsat's REST API (FastAPI) and the ``serve`` / ``worker`` commands.

Importing the routes needs no torch: the server reads stored artefacts, never live tensors.
"""
