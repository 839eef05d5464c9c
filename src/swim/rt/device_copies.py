"""Device copies of the kernels' host arrays, made once and kept while the host arrays live.

A render's chunks, and the renders of one scene and sun, share one copy of the packed volume on the device; a new
volume or a cleared stage cache drops it. Serves the JAX kernel (:func:`swim.rt.march_jax._device_constants`); the
transfer function is the caller's, so nothing here imports JAX.
"""

from __future__ import annotations

import weakref

import numpy as np



#: Device copies of the last kernel constants' host arrays for the JAX kernel (:func:`_device_constants`,
#: :func:`device_copies`).
_DEVICE_COPIES = {}
#: Every cache that :func:`device_copies` has served (the JAX kernel's volume and small constants), for
#: :func:`forget_device_copies_of`.
_COPY_CACHES = [_DEVICE_COPIES]


def kept_device_copies(hosts, cache=None):
    """The device copies that :func:`device_copies` keeps in ``cache`` (default: the JAX kernel's) for exactly the
    host arrays ``hosts`` (name -> numpy array; the same arrays owning the memory, the same views), or None where it
    keeps none of them."""
    entry = (_DEVICE_COPIES if cache is None else cache).get("entry")
    return dict(entry[1]) if _copies_of(entry, hosts) else None


def keep_device_copies(hosts, copies, cache=None):
    """Keep the device arrays ``copies`` (name -> array) as :func:`device_copies`'s copies of the host arrays ``hosts``
    (name -> numpy array, the same names and values) in ``cache`` (default: the JAX kernel's), replacing what it kept:
    for copies made on the device (a new sun's Step 1a there, :mod:`swim.rt.solar_device`) rather than sent."""
    _store_copies(_DEVICE_COPIES if cache is None else cache, hosts, copies)


def device_copies(hosts, transfer, cache):
    """Device copies ``transfer(array)`` of the host arrays ``hosts`` (name -> numpy array), made once and kept in
    ``cache`` while the arrays that own the hosts' memory live: a render's chunks, and the renders of one scene and
    sun, share them (a render may hand over new views of the same arrays). Only the last set is kept: the previous
    copies go before new ones are made, and they are dropped with their host arrays, so a new sun or a cleared
    stage cache never keeps an old volume on the device. Serves the JAX kernel
    (:func:`swim.rt.march_jax._device_constants`), with one cache for the volume and one for the small constants."""
    entry = cache.get("entry")
    if not _copies_of(entry, hosts):
        cache.clear()  # the previous copies go before the new ones are made
        entry = _store_copies(cache, hosts, {key: transfer(a) for key, a in hosts.items()})
    return entry[1]


def _copies_of(entry, hosts):
    """Whether a cache's ``entry`` (:func:`device_copies`) holds the copies of exactly the host arrays ``hosts``: the
    same arrays owning their memory, and the same views of them."""
    return (entry is not None and entry[3] == [_buffer_identity(a) for a in hosts.values()]
            and all(ref() is _owner(a) for ref, a in zip(entry[0], hosts.values())))


def _store_copies(cache, hosts, copies):
    """Keep ``copies`` (name -> device array) in ``cache`` as the copies of the host arrays ``hosts``, replacing what
    it held; they are dropped with the first host array's owner. Returns the entry."""
    if not any(known is cache for known in _COPY_CACHES):
        _COPY_CACHES.append(cache)  # for forget_device_copies_of
    owners = [_owner(a) for a in hosts.values()]
    token = object()  # what the finalizer holds: not the copies, which must not outlive the entry
    entry = ([weakref.ref(owner) for owner in owners], dict(copies), token,
             [_buffer_identity(a) for a in hosts.values()])
    cache["entry"] = entry
    weakref.finalize(owners[0], _forget_device_copies, cache, token)
    return entry


def forget_device_copies_of(host):
    """Drop the device copies (:func:`device_copies`, every cache) of the host array ``host`` or of any view of the
    array that owns its memory: its values are about to change in place."""
    owner = _owner(host)
    for cache in _COPY_CACHES:
        entry = cache.get("entry")
        if entry is not None and any(ref() is owner for ref in entry[0]):
            cache.clear()


def _forget_device_copies(cache, token):
    entry = cache.get("entry")
    if entry is not None and entry[2] is token:
        cache.clear()


def _owner(a):
    """The array that owns ``a``'s memory (the end of its chain of bases)."""
    while isinstance(a, np.ndarray) and a.base is not None:
        a = a.base
    return a


def _buffer_identity(a):
    """A host array's memory, shape, type and strides: with its owner, what identifies the values of a view."""
    return a.__array_interface__["data"][0], a.shape, a.dtype.str, a.strides
