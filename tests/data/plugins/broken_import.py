"""A plug-in module whose import fails (the test of an import error's message)."""

import a_module_that_does_not_exist  # noqa: F401
