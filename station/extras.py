"""The optional parts of an install: which third-party module belongs to which extra, and the one-line refusal
when a command or API needs an extra that is not installed.

A plain `pip install piga-station` runs a bench controller (calibrate, run, identify, simulate, export, import,
gap, sessions). The central history and cluster validations need `[fleet]`, the web panel `[web]`, the notebook
API `[notebook]`; their modules are imported only where those are used, so a missing one is found there.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

EXTRAS: dict[str, tuple[str, ...]] = {  # extra of pyproject.toml -> the top-level modules the code imports from it
    "fleet": ("sqlalchemy", "psycopg", "dask", "distributed"),
    "notebook": ("pandas", "ipykernel"),
    "web": ("fastapi", "starlette", "uvicorn", "argon2", "websockets", "multipart", "anyio", "h11"),
}
EXTRA_OF_MODULE = {module: extra for extra, modules in EXTRAS.items() for module in modules}


class MissingExtra(ImportError):  # noqa: N818 - named for what it says: an extra is missing
    """A module of an extra is not installed; the message names the extra and the pip command that adds it."""


def missing_extra(exc: ImportError, what: str) -> MissingExtra | None:
    """`exc` as a MissingExtra when the module it failed on belongs to an extra (None otherwise); `what` is the
    command or API that needed it."""
    module = (exc.name or "").partition(".")[0]
    extra = EXTRA_OF_MODULE.get(module)
    if not isinstance(exc, ModuleNotFoundError) or extra is None:
        return None
    return MissingExtra(
        f"{what} needs the [{extra}] extra ({module} is not installed): pip install 'piga-station[{extra}]'",
        name=exc.name,
    )


@contextmanager
def needs_extra(what: str) -> Iterator[None]:
    """Imports inside the block that fail on a module of an extra raise MissingExtra instead (`what` needs it)."""
    try:
        yield
    except ModuleNotFoundError as exc:
        missing = missing_extra(exc, what)
        if missing is None:
            raise
        raise missing from None
