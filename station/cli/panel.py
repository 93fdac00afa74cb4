"""`station panel` (serve the web panel) and `station panel-user` (its users); FastAPI is imported only when used."""

from __future__ import annotations

import argparse
import getpass
import os
import sys

from station.cli.console import CONFIG_DIR

DEFAULT_CONFIG = CONFIG_DIR / "panel.toml"


def _config(args: argparse.Namespace):
    from web.config import PanelConfig

    return PanelConfig.from_toml(args.config)


def panel_server(config, host: str, port: int, log_level: str = "warning"):
    """The panel under uvicorn, as `station panel` serves it (uvicorn.Server; .run() blocks).

    X-Forwarded-For is read only from the configuration's trusted_proxies (uvicorn's own default, and its
    FORWARDED_ALLOW_IPS variable, would trust loopback)."""
    import uvicorn

    from web.app import create_app

    deflate = config.websocket_compression
    proxies = list(config.trusted_proxies)
    app = create_app(config)
    return uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level=log_level, ws="websockets-sansio",
                                         ws_per_message_deflate=deflate, proxy_headers=bool(proxies),
                                         forwarded_allow_ips=proxies))  # fmt: skip


def cmd_panel(args: argparse.Namespace) -> int:
    """Serve the panel with uvicorn until Ctrl-C."""
    from web.users import UserBook

    config = _config(args)
    host = args.host or config.host
    port = config.port if args.port is None else args.port
    users = UserBook(config.users)
    if not len(users):
        print(f"station panel: no users in {config.users}: add one with "
              f"`station panel-user add NAME --role operator`", file=sys.stderr)  # fmt: skip
    server = panel_server(config, host, port, args.log_level)
    names = ", ".join(f"{s.name} ({s.control}, {s.telemetry})" for s in config.stations)
    print(f"panel on http://{host}:{port}/ for {names}; {len(users)} users in {config.users}", flush=True)
    server.run()
    return 0


def _password(args: argparse.Namespace) -> str:
    if args.password_env:
        password = os.environ.get(args.password_env)
        if not password:
            raise ValueError(f"--password-env {args.password_env}: that environment variable is not set")
        return password
    if not sys.stdin.isatty():
        raise ValueError("no terminal to ask the password on: pass --password-env VAR with the password in VAR")
    first = getpass.getpass(f"password for {args.name}: ")
    if getpass.getpass("again: ") != first:
        raise ValueError("the two passwords differ")
    return first


def cmd_panel_user(args: argparse.Namespace) -> int:
    """Add, replace, remove or list the panel's users (passwords stored as Argon2id hashes only)."""
    from web.users import UserBook

    book = UserBook(args.users or _config(args).users)
    if args.action == "list":
        for user in book.list():
            print(f"{user.name}\t{user.role}")
    elif args.action == "remove":
        book.remove(args.name)
        print(f"removed {args.name} from {book.path}")
    else:
        if not args.role:
            raise ValueError("panel-user add: --role is required: operator (may control the station) or viewer "
                             "(watches only)")  # fmt: skip
        existing = {u.name: u for u in book.list()}.get(args.name)
        if existing is not None and not _confirm_replace(args, existing.role, book.path):
            print(f"{args.name} left as it was in {book.path}", file=sys.stderr)
            return 1
        user = book.add(args.name, args.role, _password(args))
        print(f"{user.name} ({user.role}) {'replaced' if existing else 'added'} in {book.path}")
    return 0


def _confirm_replace(args: argparse.Namespace, role: str, path) -> bool:
    """Replacing a user's password and role only with --replace or a yes on the terminal."""
    if args.replace:
        return True
    if not sys.stdin.isatty():
        raise ValueError(f"user {args.name!r} ({role}) already exists in {path}: pass --replace to replace "
                         "their password and role")  # fmt: skip
    answer = input(f"user {args.name} ({role}) exists in {path}: replace their password and role? [y/N] ")
    return answer.strip().lower() in ("y", "yes")


def _guarded(func):
    """Bad configuration or input as one line on stderr and exit status 2, like the other commands."""

    def run(args: argparse.Namespace) -> int:
        from web.app import PanelSetupError
        from web.config import PanelConfigError
        from web.users import UserError

        try:
            return func(args)
        except (PanelConfigError, PanelSetupError, UserError, ValueError, OSError, EOFError) as exc:
            print(f"station {args.command}: error: {exc}", file=sys.stderr)
            return 2

    return run


def tcp_port(text: str) -> int:
    """argparse type of --port: an integer 1-65535."""
    try:
        port = int(text)
    except ValueError:
        port = 0
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not allowed: a TCP port is an integer 1-65535")
    return port


def add_commands(sub: argparse._SubParsersAction) -> None:
    """The panel's subcommands of `station`."""
    p = sub.add_parser("panel", help="serve the web panel (live view, history, control)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="panel configuration (default: config/panel.toml)")
    p.add_argument("--host", help="address to bind (default: the configuration's, 127.0.0.1)")
    p.add_argument("--port", type=tcp_port, help="TCP port, 1-65535 (default: the configuration's, 8080)")
    p.add_argument("--log-level", default="warning", choices=("debug", "info", "warning", "error"),
                   help="uvicorn's log level (default warning)")  # fmt: skip
    p.set_defaults(func=_guarded(cmd_panel))

    p = sub.add_parser("panel-user", help="add, remove or list the web panel's users")
    p.add_argument("action", choices=("add", "remove", "list"), help="add (or replace) a user, remove one, list them")
    p.add_argument("name", nargs="?", default="", help="user name (add, remove)")
    p.add_argument("--role", choices=("operator", "viewer"),
                   help="required by add: operator (may control the station) or viewer (watches only)")  # fmt: skip
    p.add_argument("--replace", action="store_true",
                   help="replace an existing user's password and role without asking")  # fmt: skip
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="panel configuration naming the users file")
    p.add_argument("--users", help="the users file itself (instead of the configuration's)")
    p.add_argument("--password-env", metavar="VAR", help="take the password from this environment variable")
    p.set_defaults(func=_guarded(cmd_panel_user))
