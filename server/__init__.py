"""modsat's job service and its front ends: the FastAPI app (app.py, routers/, schemas.py,
security.py, hosting.py of the live viewer and the page), and the ``modsat`` command line
(cli/, one module per command family).

Importing the routes needs no torch: the server reads stored artefacts, never live tensors.
"""
