"""Where numba keeps racerlab's compiled kernels, and what happens when that place is unusable or damaged.

- One folder per fingerprint of the compiled sources (`sources_key`), in the user's cache folder
  (`~/.cache/racerlab/numba/<key>`), else in a folder of this user's own in the temporary folder
  (`<tmp>/racerlab-<uid>/numba/<key>`, made 0700 and checked to be ours): never numba's cache beside the sources,
  which checks each kernel against its own file only and so runs stale code when a file it calls changes (a lap
  stayed 16.467 s after the car's speed was halved). A `NUMBA_CACHE_DIR` the user sets holds the fingerprint
  folders instead.
- racerlab's kernels are cached by `KernelCacheLocator`, put first among numba's cache locators when numba loads its
  caching module (an import hook, so that nothing in the environment names racerlab to other programs), which never
  hands them to another of numba's places: a read-only install works, and with no writable folder at all the kernels
  compile in every run, said in one line. A `NUMBA_CACHE_LOCATOR_CLASSES` the user sets is numba's to follow.
- A damaged entry (a cut or overwritten index or data file) is removed and compiled again, said in one line.
- Folders of other fingerprints unused for `KEEP_DAYS` are removed: only entries named like a fingerprint, that
  are real folders this user owns, in a cache folder that is itself no link.

Nothing here imports numba: `configure()` runs at `import racerlab`, sets the environment numba reads when it loads
and the hook; the locator is built when numba's caching module has loaded.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.util
import os
import re
import shutil
import stat
import sys
import tempfile
import time

KEEP_DAYS = 14  # cache folders of other sources unused this long are removed
_CHOSEN = "RACERLAB_KERNEL_CACHE"  # the folder this process chose, seen by its children (not a user's setting)
_KEY = re.compile(r"^[0-9a-f]{16}$")
_PACKAGE = os.path.dirname(os.path.abspath(__file__))

folder: str | None = None  # where racerlab's kernels go in this process (None: nowhere writable)
_said: set[str] = set()


def sources_key(root: str | None = None) -> str:
    """A fingerprint of the package's numba-compiled sources. numba checks each cached kernel against its own file
    only, so a kernel that calls a compiled function of another file (the simulator's step calls the car's) kept
    the old code after that other file changed (a merged car refit ran with the car before it); a cache folder
    per fingerprint cannot. `root`: the package folder (default this one)."""
    root = root or _PACKAGE
    digest = hashlib.sha1()
    for where, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "data"))
        for name in sorted(f for f in files if f.endswith(".py")):
            with open(os.path.join(where, name), "rb") as fh:
                text = fh.read()
            if b"numba" in text:
                digest.update(os.path.relpath(os.path.join(where, name), root).encode() + b"\0" + text)
    return digest.hexdigest()[:16]


def user_cache_base() -> str:
    """The user's cache folder, as the system names it."""
    if os.name == "nt":
        return os.environ.get("LOCALAPPDATA") or os.path.expanduser("~\\AppData\\Local")
    if sys.platform == "darwin":
        return os.path.expanduser("~/Library/Caches")
    return os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")


def configure(environ=os.environ) -> str | None:
    """Choose the folder of this process's kernels, tell numba (`NUMBA_CACHE_DIR`, when the user set none, read when
    numba loads) and hook racerlab's locator into numba's (`_hook`). Prunes the user cache's old fingerprint folders.
    Returns the folder (None: none writable)."""
    global folder
    key = sources_key()
    user_dir, chosen = environ.get("NUMBA_CACHE_DIR"), environ.get(_CHOSEN)
    folder = None
    if user_dir and user_dir == chosen:  # inherited from the racerlab that started this process, not the user's
        user_dir = None
        if os.path.basename(chosen) == key:  # the same sources (a worker, a child): the same kernels
            folder = _owned(chosen)
    elif user_dir:
        folder = _owned(os.path.join(user_dir, f"racerlab-{key}"))
    if folder is None:
        parent = os.path.join(user_cache_base(), "racerlab", "numba")
        tmp = _private_tmp()
        folder = _owned(os.path.join(parent, key)) or _owned(tmp and os.path.join(tmp, "numba", key))
        if folder == os.path.join(parent, key):
            prune(parent, key)
        if folder and not user_dir:
            environ["NUMBA_CACHE_DIR"] = folder
    if user_dir and folder and not folder.startswith(user_dir):
        say_once(f"NUMBA_CACHE_DIR={user_dir} cannot be written: racerlab's compiled kernels go to {folder}")
    if folder:
        environ[_CHOSEN] = folder
        try:
            os.utime(folder)  # in use: not pruned by another version's start
        except OSError:
            pass
    if "numba.core.config" in sys.modules:  # numba loaded before racerlab: it reads its environment again
        sys.modules["numba.core.config"].reload_config()
    _hook()
    return folder


def _private_tmp() -> str | None:
    """This user's own folder in the temporary folder (0700), or None when the name is taken by anything else (a
    link or a folder another user made there could hand them the kernels this process runs)."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    path = os.path.join(tempfile.gettempdir(), f"racerlab-{uid}")
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    except OSError:
        return None
    try:
        st = os.lstat(path)
    except OSError:
        return None
    private = stat.S_ISDIR(st.st_mode) and not st.st_mode & 0o077
    return path if private and (not hasattr(os, "getuid") or st.st_uid == uid) else None


def _owned(path: str | None) -> str | None:
    """`path` as a folder this user owns and can write in, made (0700) where missing; None when it cannot be."""
    if path is None:
        return None
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        st = os.lstat(path)
        mine = not hasattr(os, "getuid") or st.st_uid == os.getuid()
        if not stat.S_ISDIR(st.st_mode) or not mine:
            return None
        tempfile.TemporaryFile(dir=path).close()  # what numba's own check does: a file can be made there
    except OSError:
        return None
    return path


def prune(parent: str, keep: str) -> list[str]:
    """Remove `parent`'s fingerprint folders other than `keep` not touched for KEEP_DAYS (older racerlabs' kernels;
    another checkout in use touches its own folder at each start); returns those removed. Only entries named like a
    fingerprint that are real folders this user owns, and nothing at all when `parent` is a link: a cache folder
    linked elsewhere is not racerlab's to clear."""
    try:
        if stat.S_ISLNK(os.lstat(parent).st_mode):
            return []
        entries = list(os.scandir(parent))
    except OSError:
        return []
    old = time.time() - KEEP_DAYS * 86400
    removed = []
    for entry in entries:
        try:
            st = entry.stat(follow_symlinks=False)
            ours = not hasattr(os, "getuid") or st.st_uid == os.getuid()
            if entry.name == keep or not _KEY.match(entry.name) or not stat.S_ISDIR(st.st_mode) or not ours:
                continue
            if st.st_mtime < old:
                shutil.rmtree(entry.path)  # removes links inside as links, follows none
                removed.append(entry.name)
        except OSError:
            continue
    return removed


def say_once(text: str) -> None:
    """One line on stderr, once per process."""
    if text not in _said:
        _said.add(text)
        print(f"racerlab: {text}", file=sys.stderr, flush=True)


def _is_ours(py_file: str) -> bool:
    return os.path.abspath(py_file).startswith(_PACKAGE + os.sep)


def _hook() -> None:
    """`_install` into numba's caching module: now, when it is loaded, else when it loads (`_CachingFinder`)."""
    caching = sys.modules.get("numba.core.caching")
    if caching is not None:
        _install(caching)
    elif not any(isinstance(f, _CachingFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _CachingFinder())


class _CachingFinder(importlib.abc.MetaPathFinder):
    """Finds numba's caching module as the other finders do, with a loader that runs `_install` after it."""

    def find_spec(self, fullname, path, target=None):
        if fullname != "numba.core.caching":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            spec.loader = _InstallingLoader(spec.loader)
        return spec


class _InstallingLoader(importlib.abc.Loader):
    def __init__(self, inner) -> None:
        self.inner = inner

    def create_module(self, spec):
        return self.inner.create_module(spec)

    def exec_module(self, module) -> None:
        self.inner.exec_module(module)
        _install(module)

    def __getattr__(self, name):  # get_source and the rest, for tracebacks and inspect
        return getattr(self.inner, name)


def _install(caching) -> None:
    """racerlab's locator first among numba's, and the guards of its entries (once)."""
    if getattr(caching, "_racerlab_locator", None) is not None:
        return
    locator = _locator_class(caching)
    caching.CacheImpl._locator_classes = [locator, *caching.CacheImpl._locator_classes]
    caching._racerlab_locator = locator
    _guard(caching, locator)


def _locator_class(caching):
    class KernelCacheLocator(caching.UserProvidedCacheLocator):
        """racerlab's kernels in `folder` (one subfolder per source folder, as numba's own user-given place does);
        never None for one of them, so numba never puts them beside the sources."""

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            where = folder or os.path.join(user_cache_base(), "racerlab", "numba", "unwritable")
            self._cache_path = os.path.join(where, self.get_suitable_cache_subpath(py_file))

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _is_ours(py_file):
                return None  # another package's kernel: numba's own places, after this one
            return cls(py_func, py_file)

    return KernelCacheLocator


def _guard(caching, locator) -> None:
    """Loading one of racerlab's entries that fails (a damaged file) removes it and compiles again, with one line;
    saving one that fails (no writable folder) leaves the kernel compiled for this run only, with one line."""
    load, save = caching.Cache._load_overload, caching.Cache._save_overload

    def guarded_load(self, sig, target_context):
        if not isinstance(self._impl.locator, locator):
            return load(self, sig, target_context)
        try:
            return load(self, sig, target_context)
        except OSError:
            return None  # unreadable (a folder it may not enter): compiled, as with no entry
        except Exception as exc:  # noqa: BLE001 - whatever a damaged pickle raises (EOF, Unpickling, Overflow, ...)
            gone = _clear(self)
            say_once(f"the compiled-kernel cache entry {self._cache_file._index_name} was damaged "
                     f"({type(exc).__name__}); removed {gone} file{'' if gone == 1 else 's'} of it in "
                     f"{self._cache_path} and compiling it again")
            return None

    def guarded_save(self, sig, data):
        if not isinstance(self._impl.locator, locator):
            return save(self, sig, data)
        try:
            return save(self, sig, data)
        except OSError as exc:
            say_once(f"no writable folder for compiled kernels ({self._cache_path}: {exc.strerror}): they compile "
                     "in every run; set NUMBA_CACHE_DIR to a folder you can write")
            return None

    caching.Cache._load_overload, caching.Cache._save_overload = guarded_load, guarded_save


def _clear(cache) -> int:
    """Remove a cache entry's index and data files; how many were removed."""
    index = cache._cache_file._index_path
    base = os.path.basename(index)[: -len(".nbi")]
    gone = 0
    for name in os.listdir(cache._cache_path):
        if name == os.path.basename(index) or (name.startswith(base + ".") and name.endswith(".nbc")):
            try:
                os.remove(os.path.join(cache._cache_path, name))
                gone += 1
            except OSError:
                pass
    return gone
