"""The browser viewer (static files, no build step; see README.md here).

A package only so that its files travel inside the wheel and the sdist, and `gazehdr serve` finds
them through importlib.resources wherever gazehdr is installed (`gazehdr.viewer`).
"""
