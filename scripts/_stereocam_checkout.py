"""Import ``stereocam`` from a checkout, with setup.py's folder map, in the armhf test env.

scripts/_env.sh copies this module into the armhf rootfs's site-packages, next to a
``stereocam-checkout.pth`` that imports it in every Python process there. When
``STEREOCAM_CHECKOUT`` names a checkout (./scripts/test binds it into the rootfs and sets
it), a meta path finder maps ``stereocam``, ``stereocam.board``, ``stereocam.overlays`` and
the rest to their folders, read from setup.py's ``FOLDERS``, as the editable install
(``pip install -e .``) does in the other environments: ``stereocam.board`` is ``board/``,
``stereocam.server`` is ``server/``, and nothing else of the checkout is importable as
part of the package. The checkout is read at each start, so the rootfs holds no copy of
the project and one rootfs serves every checkout on the machine.
"""
from __future__ import annotations

import ast
import importlib.abc
import importlib.util
import os
import sys


def _folders(root: str) -> dict[str, str]:
    with open(os.path.join(root, "setup.py"), encoding="utf-8") as f:
        tree = ast.parse(f.read())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "FOLDERS"
                                                for t in node.targets):
            return {k: os.path.join(root, v) for k, v in ast.literal_eval(node.value).items()}
    raise ImportError(f"no FOLDERS in {root}/setup.py")


class CheckoutFinder(importlib.abc.MetaPathFinder):
    def __init__(self, mapping: dict[str, str]) -> None:
        self.mapping = mapping

    def find_spec(self, fullname, path=None, target=None):  # type: ignore[no-untyped-def]
        # Only the mapped packages themselves: their modules and unmapped sub-folders are
        # found by the usual path finder in the package's __path__ (its folder).
        folder = self.mapping.get(fullname)
        init = os.path.join(folder, "__init__.py") if folder else ""
        if not folder or not os.path.isfile(init):
            return None
        return importlib.util.spec_from_file_location(fullname, init, submodule_search_locations=[folder])


def install() -> None:
    root = os.environ.get("STEREOCAM_CHECKOUT")
    if not root or any(isinstance(f, CheckoutFinder) for f in sys.meta_path):
        return
    sys.meta_path.insert(0, CheckoutFinder(_folders(root)))


install()
