"""Reading what users give: one safe file reader and one safe YAML loader for every entry point.

Every file nhstab reads on a user's behalf (map files and their images, base maps and scenario
lists, run and batch configs, trajectories) goes through :func:`read_bytes`, and every YAML
document through :func:`load_yaml`: a YAML file whose top level must be a mapping (map_server
metadata, a robot, a run or batch config) through :func:`read_yaml_mapping`, and every check of a
mapping's keys (theirs and the nhstab map reader's, at any level) through :func:`check_keys`, so that
the same mistake reads the same in every kind of file. Between them they guarantee:

* only regular files are read (a FIFO, ``/dev/zero``, a directory or a symlink loop is refused, never
  read forever), and at most a bounded number of bytes (:mod:`nhstab.limits`);
* YAML is parsed with PyYAML's safe loader, and the composed node graph is checked *before* any
  Python object is built: collections nested at most ``MAX_YAML_DEPTH`` deep, at most
  ``MAX_YAML_NODES`` nodes with every alias expanded (no "billion laughs"), no recursive alias, and
  no key given twice in one mapping (YAML would silently keep the last value);
* every failure is one :class:`~nhstab.errors.InputError` (or the subclass the caller asks for) that
  names the file, the key path where it applies, what was expected and what was found.

Every file read inside :func:`recording` is logged with the SHA-256 of the bytes read, so that a map
can be identified by the content of everything it was built from (:func:`content_digest`, used by
``nhstab.maps.content_hash`` and the batch fingerprint).
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import os
import stat
from pathlib import Path

from .errors import InputError
from .limits import MAX_FILE_BYTES, MAX_YAML_BYTES, MAX_YAML_DEPTH, MAX_YAML_NODES

_RECORD: contextvars.ContextVar = contextvars.ContextVar("nhstab_files_read", default=None)


@contextlib.contextmanager
def recording():
    """Collect every file :func:`read_bytes` reads inside the block: a list of
    ``{"path", "sha256", "bytes"}`` in reading order (nested blocks see their own reads, and the
    outer block sees them too)."""
    outer = _RECORD.get()
    files: list = []
    token = _RECORD.set(files)
    try:
        yield files
    finally:
        _RECORD.reset(token)
        if outer is not None:
            outer.extend(files)


@contextlib.contextmanager
def not_recorded():
    """Reads inside this block are not recorded (a file sniffed before its loader reads it)."""
    token = _RECORD.set(None)
    try:
        yield
    finally:
        _RECORD.reset(token)


def content_digest(files) -> str:
    """The SHA-256 (hex) of the contents of ``files`` (as collected by :func:`recording`), in order.
    File names do not enter: the same bytes under another name give the same digest."""
    h = hashlib.sha256()
    for f in files:
        h.update(bytes.fromhex(f["sha256"]))
    return h.hexdigest()


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def read_bytes(path, argument: str | None = None, what: str = "file", limit: int = MAX_FILE_BYTES,
               error=InputError) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them.

    Refused, with ``error(argument or path, ...)``: a missing path, a directory, a FIFO, a device,
    a socket, a symlink loop, an unreadable file, one larger than ``limit``. A FIFO swapped in after
    the check cannot block: the file is opened non-blocking and checked again on the descriptor.
    """
    name = argument or str(path)
    where = str(path) if argument else ""          # the path, when the error names an argument
    try:
        p = os.fspath(path)
    except TypeError:
        raise error(name, f"a path to an existing {what}", f"{type(path).__name__} {path!r}") from None
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise error(name, f"an existing {what}", str(path), detail="no such file") from None
    except (OSError, ValueError) as exc:
        raise error(name, f"a readable {what}", str(path), detail=_oneline(getattr(exc, "strerror", None) or exc)) \
            from None
    if not stat.S_ISREG(st.st_mode):
        raise error(name, f"a regular {what}", _kind(st.st_mode), detail=where)
    if st.st_size > limit:
        raise error(name, f"a {what} of at most {limit:,} bytes", f"{st.st_size:,} bytes", detail=where)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise error(name, f"a readable {what}", str(path), detail=_oneline(exc.strerror or exc)) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(name, f"a regular {what}", _kind(st.st_mode), detail=where)
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise error(name, f"a readable {what}", str(path), detail=_oneline(exc.strerror or exc)) from None
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > limit:
        raise error(name, f"a {what} of at most {limit:,} bytes", "more (it grew while being read)", detail=where)
    files = _RECORD.get()
    if files is not None:
        files.append({"path": str(Path(p).resolve()), "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)})
    return data


def read_text(path, argument: str | None = None, what: str = "file", limit: int = MAX_FILE_BYTES,
              error=InputError) -> str:
    """:func:`read_bytes` decoded as UTF-8 (a file that is not UTF-8 is refused, naming the byte)."""
    data = read_bytes(path, argument, what, limit, error)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(argument or str(path), f"a UTF-8 text {what}", str(path),
                    detail=f"byte {exc.start}: {_oneline(exc.reason)}") from None


# ---- YAML -------------------------------------------------------------------------------------

def load_yaml_file(path, argument: str | None = None, what: str = "YAML file", error=InputError):
    """Read ``path`` (:func:`read_text`, at most ``MAX_YAML_BYTES``) and :func:`load_yaml` it.
    Errors about reading name ``argument`` (or the path); errors in the document name the argument,
    the path and the key path inside it (e.g. ``--config run.yaml: noise.scale``)."""
    text = read_text(path, argument, what, MAX_YAML_BYTES, error)
    return load_yaml(text, f"{argument} {path}" if argument else str(path), error)


def read_yaml_mapping(path, argument: str | None = None, what: str = "YAML file", keys=None, required=(),
                      error=InputError) -> dict:
    """The one loader of nhstab's YAML files (maps' map_server metadata, robots, run and batch configs;
    the nhstab map reader parses its text with the same :func:`load_yaml` and checks its keys with the
    same :func:`check_keys`): a YAML file whose top level is a mapping, read by :func:`load_yaml_file`
    (regular files only, bounded size, nesting and alias expansion, duplicate keys refused).

    ``keys``: the top-level keys allowed (None: any text key, for a file whose keys its reader checks,
    as a robot's depend on its model), ``required`` those that must be there. Errors name the document
    as its duplicate keys do, ``argument`` then the path (e.g. ``--config run.yaml``), and a key after a
    colon (``--config run.yaml: bogus``)."""
    data = load_yaml_file(path, argument, what, error)
    source = f"{argument} {path}" if argument else str(path)
    if data is None:
        raise error(source, f"a {what} holding a YAML mapping", "an empty document")
    if keys is None:
        if not isinstance(data, dict):
            raise error(source, f"a {what} holding a YAML mapping", yaml_type_name(data), detail="at top level")
        for key in data:
            if not isinstance(key, str):
                raise error(_at(source, str(key)), "a text key", yaml_type_name(key))
        return data
    return check_keys(data, tuple(keys), source, "", error, tuple(required))


def check_keys(value, allowed: tuple[str, ...], source: str, key: str = "", error=InputError,
               required: tuple[str, ...] = ()) -> dict:
    """``value`` as a mapping whose keys are among ``allowed`` and include ``required``: the one
    unknown-key check of nhstab's YAML files. Errors name ``source`` (the file) and the key path
    ``key`` (empty at the top level): ``'<source>: <key>.<unknown>' must be one of the keys ...; got
    "unknown key '<unknown>'"``."""
    label = key or "top level"
    if not isinstance(value, dict):
        raise error(_at(source, key), f"a mapping with keys {', '.join(allowed)}", yaml_type_name(value),
                    detail=f"at {label}")
    for k in value:
        if not isinstance(k, str) or k not in allowed:
            raise error(_at(source, f"{key}.{k}" if key else str(k)), f"one of the keys {', '.join(allowed)}",
                        f"unknown key {k!r}")
    for k in required:
        if k not in value:
            raise error(_at(source, f"{key}.{k}" if key else k), "present", "missing", detail=f"required in {label}")
    return value


def yaml_type_name(value) -> str:
    """What a YAML value is, for error messages: "a list", "an integer", "nothing (null)", ..."""
    if value is None:
        return "nothing (null)"
    return {dict: "a mapping", list: "a list", str: "a string", bool: "a boolean",
            int: "an integer", float: "a number"}.get(type(value), type(value).__name__)


def _at(source: str, key: str) -> str:
    return f"{source}: {key}" if key else source


def load_yaml(text: str, source: str, error=InputError):
    """Parse one YAML document safely (see the module docstring); ``source`` names it in errors.

    An empty document gives None. Errors: ``error(source or "source: key.path", expected, got)``.
    """
    import yaml

    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise error(source, "UTF-8 YAML text", detail=f"byte {exc.start}: {_oneline(exc.reason)}") from None
    if len(text) > MAX_YAML_BYTES:
        raise error(source, f"a YAML document of at most {MAX_YAML_BYTES:,} characters", f"{len(text):,}")
    loader = _Loader(text)
    try:
        try:
            node = loader.get_single_node()
        except _TooDeep as deep:
            raise error(source, f"YAML nested at most {MAX_YAML_DEPTH} levels deep", f"deeper at {deep.where}") \
                from None
        except yaml.YAMLError as exc:
            raise error(source, "valid YAML", detail=_yaml_message(exc)) from None
        except RecursionError:        # pragma: no cover - the depth bound comes first
            raise error(source, f"YAML nested at most {MAX_YAML_DEPTH} levels deep", "deeper") from None
        if node is None:
            return None
        _check_graph(node, source, error)
        try:
            return loader.construct_document(node)
        except yaml.YAMLError as exc:
            raise error(source, "valid YAML", detail=_yaml_message(exc)) from None
        except (ValueError, TypeError, OverflowError, ArithmeticError) as exc:   # bad timestamps, base64, ...
            raise error(source, "valid YAML values", detail=f"{type(exc).__name__}: {_oneline(exc)}"[:200]) from None
    finally:
        loader.dispose()


class _TooDeep(Exception):
    def __init__(self, where: str):
        super().__init__(where)
        self.where = where


def _make_loader():
    """PyYAML's safe loader with a composer that refuses to nest deeper than the limit. PyYAML
    composes recursively (and libyaml's own composer recurses in C, unbounded), so composition
    always runs in Python here; libyaml's parser, a state machine with explicit stacks, supplies the
    events when it is installed (faster than the pure-Python scanner)."""
    import yaml
    from yaml.composer import Composer

    class _Bounded:
        def compose_node(self, parent, index):
            self._depth = getattr(self, "_depth", 0) + 1
            try:
                if self._depth > MAX_YAML_DEPTH:
                    mark = self.peek_event().start_mark
                    raise _TooDeep(f"line {mark.line + 1}, column {mark.column + 1}")
                return Composer.compose_node(self, parent, index)
            finally:
                self._depth -= 1

    if getattr(yaml, "__with_libyaml__", False):
        from yaml.constructor import SafeConstructor
        from yaml.cyaml import CParser
        from yaml.resolver import Resolver

        class Loader(_Bounded, CParser, SafeConstructor, Resolver):
            def __init__(self, stream):
                CParser.__init__(self, stream)
                SafeConstructor.__init__(self)
                Resolver.__init__(self)
                self.anchors = {}

            get_single_node = Composer.get_single_node
            compose_document = Composer.compose_document
            compose_scalar_node = Composer.compose_scalar_node
            compose_sequence_node = Composer.compose_sequence_node
            compose_mapping_node = Composer.compose_mapping_node

        return Loader

    class Loader(_Bounded, yaml.SafeLoader):       # pragma: no cover - PyYAML without libyaml
        pass

    return Loader


_LOADER_CLASS = None


def _Loader(text):
    global _LOADER_CLASS
    if _LOADER_CLASS is None:
        _LOADER_CLASS = _make_loader()
    return _LOADER_CLASS(text)


_MERGE = "tag:yaml.org,2002:merge"


def _check_graph(root, source: str, error) -> None:
    """Before construction: expanded size and depth (aliases counted as copies), no recursive alias,
    no duplicate key. Memoised per node, so an alias bomb is measured in time linear in the text."""
    from yaml.nodes import ScalarNode, SequenceNode

    memo: dict[int, tuple[int, int]] = {}
    active: set[int] = set()

    def where(path: str) -> str:
        return f"{source}: {path}" if path else source

    def visit(node, path: str) -> tuple[int, int]:
        key = id(node)
        if key in memo:
            return memo[key]
        if key in active:
            raise error(where(path), "data without recursive aliases", "an alias that contains itself",
                        detail=f"line {node.start_mark.line + 1}")
        if isinstance(node, ScalarNode):
            memo[key] = (1, 0)
            return memo[key]
        active.add(key)
        size, depth = 1, 0
        if isinstance(node, SequenceNode):
            children = [(child, f"{path}[{i}]") for i, child in enumerate(node.value)]
        else:
            children, seen = [], {}
            for k, v in node.value:
                label = k.value if isinstance(k, ScalarNode) else "?"
                if isinstance(k, ScalarNode) and k.tag != _MERGE:
                    ident = (k.tag, k.value)
                    if ident in seen:
                        sub = f"{path}.{label}" if path else str(label)
                        raise error(where(sub), "a key given once in its mapping",
                                    f"a second {label!r} at line {k.start_mark.line + 1}",
                                    detail=f"the first is at line {seen[ident] + 1}; YAML would keep the last "
                                           "value silently")
                    seen[ident] = k.start_mark.line
                sub = f"{path}.{label}" if path else str(label)
                children.append((k, sub))
                children.append((v, sub))
        for child, sub in children:
            s, d = visit(child, sub)
            size += s
            depth = max(depth, d + 1)
            if size > MAX_YAML_NODES:
                raise error(where(path), f"YAML of at most {MAX_YAML_NODES:,} values with aliases expanded",
                            "more", detail="an alias bomb?")
            if depth > MAX_YAML_DEPTH:
                raise error(where(path), f"YAML nested at most {MAX_YAML_DEPTH} levels deep with aliases "
                            "expanded", "deeper")
        active.discard(key)
        memo[key] = (size, depth)
        return memo[key]

    visit(root, "")


def _yaml_message(exc) -> str:
    return _oneline(str(exc).replace(' in "<unicode string>",', " at"))[:240]


def _oneline(value) -> str:
    return " ".join(str(value).split())
