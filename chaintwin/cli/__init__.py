"""The ``chaintwin`` command line: thin wrappers over the library's stages."""
