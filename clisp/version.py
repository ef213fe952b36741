"""clisp's version (one place; ``clisp.__version__`` re-exports it)."""
__version__ = "0.1.0"
