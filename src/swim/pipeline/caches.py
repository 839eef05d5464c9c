"""What the renders of a process share (:data:`STATE`): the stage cache, the last scene's digest and the count of
renders running; and the scenes' digests that key the stages.

A time series, several cameras on one scene or a fly-through would otherwise rebuild the optical volume, Step 1a and
the kernel tables every frame, which on a big grid takes longer than the march (docs/decisions/0007-scene-set-up.md).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import weakref

import numpy as np
import xarray as xr
import xxhash

from ..digest import update_with_array
from ..rt.march_settings import MarchSettings
from ..workers import parallel_map, threads

log = logging.getLogger(__name__)

#: Scenes of at least this many bytes are hashed on several threads (:func:`fingerprint`): below it the pool's
#: overhead (~0.1 ms) is not worth it.
FINGERPRINT_THREADED_BYTES = 64 << 20



def fingerprint(scene: xr.Dataset) -> str:
    """Digest of a scene's values, coordinates and attributes (what its optical volume depends on).

    The scene as given to :func:`render` (cropped, not yet validated: the same values validate to the same
    scene, and a warm render then skips the validation's float64 copies). A streaming XXH3-128 digest (``xxhash``)
    of each variable's name, dims, dtype, shape and attributes and of its values (:mod:`swim.digest`); then one of
    those digests, in the variables' sorted order, and of the scene's attributes. The variables of a big scene are
    hashed on up to 8 threads (xxhash releases the GIL): the 12 MB RICO LES takes ~0.4 ms per render (7 ms with
    SHA-256 on the thread pool), the 0.47 GB of the 400 x 400 x 60 benchmark scene ~17 ms on one core here and
    75 ms on one core of the H100 machine's host (docs/decisions/0009-work-around-the-march.md and
    docs/decisions/0006-gpu-kernels.md)."""
    names = sorted(scene.variables)

    def variable_digest(name):
        var = scene.variables[name]
        digest = xxhash.xxh3_128()
        # the attributes too: validation checks the units, and a warm render does not validate again
        digest.update(f"{name}{var.dims}{var.dtype}{var.shape}{_attrs_text(var.attrs)}".encode())
        values = var.values
        if values.dtype.kind not in "biufc":
            digest.update(repr(values.tolist()).encode())
        else:
            update_with_array(digest, values)
        return digest.digest()

    size = sum(scene.variables[name].nbytes for name in names)
    parts = parallel_map(variable_digest, names, min(threads(), 8) if size >= FINGERPRINT_THREADED_BYTES else 1)
    digest = xxhash.xxh3_128(b"".join(parts))
    digest.update(_attrs_text(scene.attrs).encode())
    return digest.hexdigest()



#: Arrays of at least this many bytes are known by their identity in :func:`scene_identity` (smaller ones by their
#: values' digest, which costs less than a microsecond per kilobyte).
IDENTITY_MIN_BYTES = 1 << 20



def scene_identity(scene: xr.Dataset):
    """What makes a scene the same one as a render's before, short of hashing its big arrays: each variable's name,
    dims, dtype, shape and attributes; for an array of at least :data:`IDENTITY_MIN_BYTES`, the array that owns its
    memory (its id and a weak reference to it: while that lives, no other array can take its place) with the view's
    address and strides; for a smaller one, its values' digest; and the scene's attributes. None where a big
    variable is not a NumPy array (a lazy one). Values changed in place leave the identity as it was: a render that
    takes a digest by identity checks it (:func:`fingerprint_by_identity`)."""
    parts = []
    for name in sorted(scene.variables):
        var = scene.variables[name]
        head = f"{name}{var.dims}{var.dtype}{var.shape}{_attrs_text(var.attrs)}"
        data = getattr(var, "_data", None)
        if isinstance(data, np.ndarray) and data.nbytes >= IDENTITY_MIN_BYTES:
            root = data
            while isinstance(root.base, np.ndarray):
                root = root.base
            parts.append((head, id(root), weakref.ref(root), data.__array_interface__["data"][0], data.strides))
        elif var.nbytes >= IDENTITY_MIN_BYTES:
            return None
        else:
            digest = xxhash.xxh3_128()
            values = var.values
            if values.dtype.kind not in "biufc":
                digest.update(repr(values.tolist()).encode())
            else:
                update_with_array(digest, values)
            parts.append((head, digest.digest()))
    return tuple(parts), _attrs_text(scene.attrs)



def same_identity(a, b) -> bool:
    """Whether two :func:`scene_identity` values are of the same arrays (weak references compared by their
    referents' identity, never by ``==`` on arrays)."""
    if a is None or b is None or a[1] != b[1] or len(a[0]) != len(b[0]):
        return False
    for x, y in zip(a[0], b[0]):
        if len(x) != len(y) or x[0] != y[0]:
            return False
        if len(x) == 2:
            if x[1] != y[1]:
                return False
        elif x[1] != y[1] or x[2]() is None or x[2]() is not y[2]() or x[3:] != y[3:]:
            return False
    return True



class LastDigest:
    """The identity (:func:`scene_identity`) and digest (:func:`fingerprint`) of the last in-memory scene rendered
    in this process."""

    def __init__(self):
        self._lock = threading.Lock()
        self._entry = None

    def digest_of(self, identity):
        with self._lock:
            entry = self._entry
        return entry[1] if entry is not None and same_identity(entry[0], identity) else None

    def remember(self, identity, digest):
        with self._lock:
            self._entry = None if identity is None else (identity, digest)

    def forget(self):
        with self._lock:
            self._entry = None



class StaleDigest(Exception):
    """A digest taken by identity did not hold (the scene's values changed in place): :func:`render` renders again."""



class DigestGuess:
    """A render's digest taken by the scene's identity (:func:`fingerprint_by_identity`) and its check: the scene
    hashed on a thread of its own while the render goes on (one thread per check: renders on several threads hash
    at once, and a forked process starts none of its parent's)."""

    def __init__(self):
        self.guess = None
        self._done = threading.Event()
        self._actual = self._error = None

    def start(self, guess, scene) -> bool:
        """Check ``guess`` against ``scene``'s digest on a new thread; False where no thread can start (the
        interpreter shutting down: the caller hashes the scene itself)."""
        def check():
            try:
                self._actual = fingerprint(scene)
            except BaseException as err:  # noqa: BLE001 - raised again by held()
                self._error = err
            finally:
                self._done.set()

        try:
            threading.Thread(target=check, name="swim-digest-check", daemon=True).start()
        except RuntimeError:
            return False
        self.guess = guess
        return True

    def held(self) -> bool:
        """Whether the guess was the scene's digest (True where none was taken); waits for the check."""
        if self.guess is None:
            return True
        self._done.wait()
        if self._error is not None:
            raise self._error
        return self._actual == self.guess



def speculate_digest(settings: MarchSettings) -> bool:
    """Whether a render may take an in-memory scene's digest by its arrays' identity and check it meanwhile: where
    the march runs on a GPU (its host idles while the device marches); on a CPU the march takes the cores."""
    return settings.on_accelerator()



def fingerprint_by_identity(scene: xr.Dataset, guess: DigestGuess | None) -> str:
    """:func:`fingerprint` of an in-memory scene, or, with ``guess``, perhaps the last rendered scene's.

    With ``guess``, where the scene has the last rendered scene's identity (:func:`scene_identity`: the same
    arrays, attributes and small values) and the stage cache still holds that scene's optical volume, the last
    digest is returned at once and ``guess`` checks it on another thread meanwhile (:meth:`DigestGuess.held`,
    which :func:`render` asks before it returns, and the volume's build before it builds anything under the guessed
    digest). In an H100 frame of the 400 x 400 x 60 scene the hash of its 0.47 GB took ~14 ms of the host's
    0.135 s (docs/decisions/0006-gpu-kernels.md). Otherwise the digest is computed here, and with ``guess``
    remembered with the identity."""
    if guess is None:
        return fingerprint(scene)
    identity = scene_identity(scene)
    if identity is not None:
        last = STATE.last_digest.digest_of(identity)
        if last is not None and STATE.stages.peek(("volume", last)) is not None and guess.start(last, scene):
            return last
    digest = fingerprint(scene)
    STATE.last_digest.remember(identity, digest)
    return digest



def is_lazy(scene: xr.Dataset) -> bool:
    """Whether any variable of ``scene`` is a chunked (dask) array. ``Variable.chunks`` checks its array against a
    runtime protocol (~13 us a variable); an index variable, or a variable whose array is a numpy array (xarray's
    ``_data``, looked up with a fallback to ``chunks``), is answered at once. Not ``Variable.data``: for a lazily
    opened file that reads it."""
    return any(not isinstance(var, xr.IndexVariable) and not isinstance(getattr(var, "_data", None), np.ndarray)
               and var.chunks is not None for var in scene.variables.values())  # an index is held in memory



def lazy_fingerprint(scene: xr.Dataset) -> str:
    """Digest of a lazy (dask-backed) scene without reading it: its dask token, which covers the graph of every
    variable (the names of the files and their modification times for an opened file, the tokens of the
    operations on them, such as the crop), the in-memory variables' values and all attributes. dask names its
    arrays by the same token and relies on it for its own caching. What it does not see: a file replaced by one
    with the same name and modification time (``cp -p``, ``rsync -t``), a file rewritten while a dataset opened
    from it is still in use (its token was made when it was opened; open it again), and a numpy array wrapped by
    ``dask.array.from_array`` and changed in place afterwards (wrap it again). ``swim.pipeline.STATE.forget()``
    forgets every cached stage."""
    import dask.base

    return "dask-" + dask.base.tokenize(scene)



def _attrs_text(attrs):
    return repr(sorted((k, repr(v)) for k, v in attrs.items()))



class StageCache:
    """The last render's optical volume, Step 1a and kernel constants, reused while the scene (and the sun and
    the atmosphere) stay the same.

    A time series, several cameras on one scene or a fly-through would otherwise rebuild them every frame,
    which on a big grid takes longer than the ray march (docs/performance.md). Keys are (kind, scene
    fingerprint, ...); one entry of each kind. Before an entry is rebuilt, it and every entry of another
    scene are dropped, so the cache never holds two grids at once. Small values that do not hold a grid (the 3-D
    diffuse solutions) are kept across scenes, a few at a time (:meth:`get_small`)."""

    def __init__(self):
        self._entries = {}
        self._small = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, key, build):
        kind, fingerprint = key[:2]
        entry = self._entries.get(kind)
        if entry is not None and entry[0] == key:
            log.info("reusing the %s of the previous render", kind)
            return entry[1]
        self._drop_for(key)  # before the build: the cache never holds two grids at once
        return self.put(key, build())

    def peek(self, key):
        """The value kept under ``key``, or None (nothing is built or dropped)."""
        entry = self._entries.get(key[0])
        return entry[1] if entry is not None and entry[0] == key else None

    def put(self, key, value):
        """Keep ``value`` under ``key`` (replacing its kind's entry; entries of other scenes are dropped) and return
        it."""
        self._drop_for(key)
        self._entries[key[0]] = (key, value)
        return value

    def _drop_for(self, key):
        """Drop the entry of ``key``'s kind and every entry of another scene."""
        kind, fingerprint = key[:2]
        for other, (other_key, _) in list(self._entries.items()):
            if other == kind or other_key[1] != fingerprint:
                self._entries.pop(other, None)  # (another render's thread may have dropped it already)

    def get_small(self, key, build, named=None):
        """The value of ``key`` from a store of :data:`SMALL_ENTRIES` small values kept across scenes (the least
        recently used goes first), else ``build()``'s, kept. ``named``: the object whose ``id`` the key holds (the
        gas tables), referenced weakly: an entry whose object has gone (its id may be another's now) is not used."""
        with self._lock:
            entry = self._small.get(key)
            if entry is not None and (entry[1] is None or entry[1]() is named):
                self._small.move_to_end(key)
                log.info("reusing the %s of an earlier render", key[0])
                return entry[0]
        value = build()
        with self._lock:
            self._small[key] = (value, None if named is None else weakref.ref(named))
            while len(self._small) > SMALL_ENTRIES:
                self._small.popitem(last=False)
        return value

    def clear(self):
        self._entries.clear()
        self._small.clear()



#: Small stage values kept across scenes (:meth:`StageCache.get_small`): the 3-D diffuse solutions (a few MB each),
#: which renders that alternate between scenes, aerosols or sun nodes would otherwise solve again.
SMALL_ENTRIES = 4



class RenderState:
    """What the renders of this process share: the stage cache (:attr:`stages`), the last in-memory scene's digest
    (:attr:`last_digest`), the lock under which a render builds its grid's tables (:attr:`grid_tables_lock`) and the
    count of renders running.

    Renders may run on several threads at once (a dask worker's, a caller's own). The build of a grid's tables reads
    the cached optical volume and may point its extinctions at a new packed volume
    (:func:`swim.rt.march_inputs.share_packed_channels`), which deletes and re-adds its ``species`` coordinate: a
    render beside it read the volume in between and found the coordinate gone, so the builds take turns. A new sun
    refills the shared packed volume in place only where its render is the only one running
    (:meth:`rendering_alone`)."""

    def __init__(self):
        self.stages = StageCache()
        self.last_digest = LastDigest()
        self.grid_tables_lock = threading.RLock()
        self._running = 0
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def rendering(self):
        """Count a render as running while the block runs."""
        with self._lock:
            self._running += 1
        try:
            yield
        finally:
            with self._lock:
                self._running -= 1

    def running(self) -> int:
        """How many renders are running in this process."""
        with self._lock:
            return self._running

    def rendering_alone(self) -> bool:
        """Whether the calling render is the only one running in this process."""
        return self.running() <= 1

    def forget(self):
        """Forget every stage and the last digest: the next render builds everything from its scene's values."""
        self.last_digest.forget()
        self.stages.clear()


#: The process's one :class:`RenderState`.
STATE = RenderState()
