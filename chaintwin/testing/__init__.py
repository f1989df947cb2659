"""Support for the tests and the benchmarks; nothing in the commands or the library imports it.

:mod:`chaintwin.testing.postgres` starts a throwaway PostgreSQL server. The
layers contract (``[tool.importlinter]`` in ``pyproject.toml``) keeps this
package on top: it may import every part, no part may import it.
"""
