"""Named run profiles: ``NAME.toml`` here is ``--profile NAME`` and ``load_config("NAME")``.

Installed as the package ``sagp_batched.profiles`` (pyproject.toml maps this folder), so named profiles
resolve through ``importlib.resources`` from a wheel and from an editable install alike. It is a regular
package, not a namespace one, because setuptools' editable finder does not import a namespace
subpackage whose folder lies outside its parent's.
"""
