"""oscar's built-in embodiments, one plugin per sub-package.

Each sub-package is written exactly as an outside plugin would be: a module
with an ``oscar_register_embodiments`` hookimpl, its assets, and a README
stating provenance, license and conventions. They register through the
``oscar`` entry-point group like any other plugin.
"""
