"""Everything a browser sees: the service's page (``static/``: HTML, scripts and styles, served at
``/`` by ``modsat serve``; server/hosting.py) and the viser 3D viewer (:mod:`web.viewer`: scenes,
live sessions, ``.viser`` recordings). This package's face imports neither."""
