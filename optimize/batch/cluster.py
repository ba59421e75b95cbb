"""How a batch reaches Ray: a Ray of its own that only this user on this machine can reach, or a cluster that
checks who joins it.

**Local** (no `--address`, no RAY_ADDRESS): a new Ray instance of the batch's own (`address="local"`: never a
head that happens to run on the machine, whose CPUs and owner are not the batch's), with no dashboard, its servers
listening on the loopback interface only and checking Ray's auth token, so that neither other machines nor other
users of this one can run code in it. Ray 2.60 listens on every interface unless a node's address is 127.0.0.1,
and rewrites 127.0.0.1 to the machine's own address unless multi-node clusters are off; `_loopback_only` turns
them off while the instance starts (RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, Ray's switch for Windows and macOS,
which `ray._private.ray_constants` reads once, at import). The token is Ray's own: ~/.ray/auth_token, which Ray
creates on a first run (readable by everyone; made readable by its owner only when this batch created it), and
which a head started later on this machine with `ray start --head` uses too.

**Cluster** (`--address HOST:PORT`, or RAY_ADDRESS, as `ray job submit` sets it for its entrypoint): the head
must check Ray's auth tokens. Before joining, one request without a token tells whether it does (Ray's own client
would send one to a head that does not care, and join it silently), and one with this machine's token whether the
head takes it; each answer that is not yes is an error that says what to do, in seconds, where Ray retries for
20 s and reports only "Failed to connect". A head that checks no tokens is joined only when the user says so with
RAY_AUTH_MODE=disabled, Ray's own switch. docs/cluster.md says how to run a cluster safely.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
from pathlib import Path

from warp_hair.devices import native_stderr_without

AUTH_MODE = "RAY_AUTH_MODE"  # Ray's switch: "token" or "disabled"; unset, Ray decides (and so do we)
MULTI_NODE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
REACH_SECONDS = 5.0  # a head that does not accept a TCP connection within this is not there
DOCS = "docs/cluster.md, 'Running a cluster safely'"


def connect(address: str | None, cpus: int | None) -> bool:
    """Join or start Ray as the module docstring says; True when this call started it (and so should stop it).
    A ValueError says what is wrong and what to do: Ray missing, a head out of reach, a token missing or refused,
    a head that checks no tokens. A Ray already initialised in this process (a test's, a notebook's) is used as
    it is."""
    try:
        import ray
    except ImportError:
        raise ValueError(
            "warp-hair batch needs Ray: pip install -e \".[cluster]\" (or pip install 'ray>=2.60')"
        ) from None
    if ray.is_initialized():
        return False
    # Under `ray job submit`, or wherever a cluster is named in the environment, join it as Ray's own tools do.
    address = address or os.environ.get("RAY_ADDRESS") or "local"
    if address == "local":
        if cpus is None:
            cpus = len(os.sched_getaffinity(0))
        _start_local(cpus)
    else:
        if cpus is not None:
            raise ValueError(
                "--cpus sets the CPUs of the Ray a batch starts on this machine; a cluster's nodes have the CPUs "
                "their `ray start` gave them: leave --cpus out with --address"
            )
        _join(address)
    return True


@contextlib.contextmanager
def ray_messages_off():
    """Ray's own messages on the driver's terminal off (its workers' output does not come at all:
    log_to_driver=False). Ray reports each worker's death and the task's retry in long lines of IDs that break
    the progress bar; the batch reports per job what became of it, and Ray's logs keep them. Ray's own debugger
    turns them off so (ray.util.rpdb)."""
    from ray._private import worker

    saved = worker._worker_logs_enabled
    worker._worker_logs_enabled = False
    try:
        yield
    finally:
        worker._worker_logs_enabled = saved


def _start_local(cpus: int) -> None:
    import ray

    # Ray's default for a new local instance, set here so that Ray does not warn about it on every batch.
    _set_auth_mode(os.environ.get(AUTH_MODE, "token"))
    token = Path.home() / ".ray" / "auth_token"
    existed = token.exists()
    with _loopback_only():
        ray.init(
            address="local",
            num_cpus=cpus,
            include_dashboard=False,
            log_to_driver=False,  # the jobs' warnings and errors come back with their results (runner.py)
            logging_level=logging.WARNING,
            _node_ip_address="127.0.0.1",
        )
    if not existed and token.exists():
        token.chmod(0o600)


@contextlib.contextmanager
def _loopback_only():
    """Ray's node address 127.0.0.1 while a local instance starts (see the module docstring); its processes keep
    the setting, this process gets its own back."""
    from ray._private import ray_constants

    saved = os.environ.get(MULTI_NODE), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[MULTI_NODE] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        _restore(MULTI_NODE, saved[0])
        ray_constants.ENABLE_RAY_CLUSTER = saved[1]


def _join(address: str) -> None:
    import ray

    host, port = _host_port(address)
    where = f"the Ray cluster at {host}:{port}"
    try:
        socket.create_connection((host, port), timeout=REACH_SECONDS).close()
    except OSError as error:
        raise ValueError(
            f"cannot reach {where} ({error}): is `ray start --head --port {port}` running there, and is the port "
            "open to this machine?"
        ) from None
    asked = os.environ.get(AUTH_MODE)
    checks_tokens = not _answers(host, port, "disabled")
    if asked == "disabled":
        if checks_tokens:
            raise ValueError(
                f"{where} checks Ray's auth tokens, and RAY_AUTH_MODE=disabled here sends none: unset "
                f"RAY_AUTH_MODE and give this machine the head's token ({DOCS})"
            )
    elif not checks_tokens:
        raise ValueError(
            f"{where} does not check Ray's auth tokens: anyone who reaches its ports can run code on its nodes. "
            "Restart it with token authentication (`ray get-auth-token --generate`, then `RAY_AUTH_MODE=token "
            "ray start --head ...`, the same token on every node), or, on a network that only you reach, set "
            f"RAY_AUTH_MODE=disabled to join it as it is ({DOCS})"
        )
    else:
        from ray._raylet import AuthenticationTokenLoader

        _set_auth_mode("token")
        if not AuthenticationTokenLoader.instance().has_token(ignore_auth_mode=True):
            raise ValueError(
                f"{where} checks Ray's auth tokens and this machine has none: copy the head's (`ray "
                f"get-auth-token` there) to {Path.home() / '.ray' / 'auth_token'} (chmod 600), or name its file in "
                f"RAY_AUTH_TOKEN_PATH ({DOCS})"
            )
        if not _answers(host, port, "token"):
            raise ValueError(
                f"{where} refuses this machine's Ray auth token ({_token_source()}): it is not the head's; copy "
                f"the head's (`ray get-auth-token` there) ({DOCS})"
            )
    try:
        ray.init(address=f"{host}:{port}", log_to_driver=False, logging_level=logging.WARNING)
    except RuntimeError as error:  # e.g. another Ray version on the cluster
        raise ValueError(f"cannot join {where}: {error}") from None


def _host_port(address: str) -> tuple:
    if address == "auto":  # Ray's "the cluster `ray start` started on this machine"
        from ray._private.services import canonicalize_bootstrap_address_or_die

        address = canonicalize_bootstrap_address_or_die("auto")
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(
            f"--address (or RAY_ADDRESS) must be the Ray head's HOST:PORT (the port of `ray start --head --port`), "
            f"got {address!r}"
        )
    return host.strip("[]"), int(port)


def _answers(host: str, port: int, mode: str) -> bool:
    """Whether the head's GCS answers a request sent with Ray's auth `mode` ("disabled": no token; "token": this
    machine's token). Ray's C++ client logs its refusal to stderr itself; that line is left out."""
    from ray._raylet import GcsClient
    from ray.exceptions import AuthenticationError, RayError

    saved = os.environ.get(AUTH_MODE)
    _set_auth_mode(mode)
    try:
        with native_stderr_without(None):  # the C++ client's own complaints: the error says it
            GcsClient(address=f"{host}:{port}").internal_kv_get(b"-", b"warp-hair", timeout=REACH_SECONDS)
        return True
    except AuthenticationError:
        return False
    except RayError as error:  # something else listens there, or a head too busy to answer
        raise ValueError(f"{host}:{port} does not answer as a Ray head ({type(error).__name__}: {error})") from None
    finally:
        _set_auth_mode(saved)


def _set_auth_mode(mode: str | None) -> None:
    """Ray's auth mode for this process, as Ray itself sets it (authentication_token_setup._enable_token_auth)."""
    from ray._raylet import Config

    _restore(AUTH_MODE, mode)
    Config.initialize("")


def _token_source() -> str:
    if os.environ.get("RAY_AUTH_TOKEN"):
        return "RAY_AUTH_TOKEN"
    return os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")


def _restore(name: str, value: str | None) -> None:
    if value is None:
        os.environ.pop(name, None)
    else:
        os.environ[name] = value
