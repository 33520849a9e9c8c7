"""The exceptions jaxrbf raises. Every message names the argument or file, what was expected and a fix."""


class JaxRBFError(Exception):
    """Base class of every error jaxrbf raises on purpose."""


class InputError(JaxRBFError, ValueError):
    """Bad input: a file, an array or an option that jaxrbf cannot use as given."""


class SolveError(JaxRBFError, RuntimeError):
    """The linear system could not be solved, or its solution does not reproduce the constraints."""
