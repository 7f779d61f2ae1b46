"""Values of frames in flight: :class:`Slot` (one value of one frame, where its producer left
it), :class:`Flag` (its one-shot ready signal) and :class:`Ring` (a delay's slots of past
frames)."""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

from .native_copy import synchronize_event

if TYPE_CHECKING:
    from .transfers import Transfers

_GUARD_INIT = threading.Lock()  # makes a slot's copy lock, or a flag's, once

#: Where a slot's value lives: host memory (NumPy) or the GPU role's device (``wp.array``).
HOST = "host"
DEVICE = "device"


class Flag:
    """A one-shot ``threading.Event`` (``set``, ``is_set``, ``wait(timeout)``): a bool,
    ``ready``, and a lock made only when a thread has to block on it. The executor makes one
    per value per frame (every :class:`Slot` is its own flag) and, with one-frame schedules,
    never blocks on them (a task runs once its inputs are set), so most flags never make
    their lock. Hot loops read ``ready`` (what ``is_set()`` returns) without a call."""

    __slots__ = ("_waiters", "ready")

    def __init__(self):
        self._waiters = None
        self.ready = False

    def set(self):
        if not self.ready:
            self.ready = True  # before looking at the lock: a waiter making it looks at ready after
            if self._waiters is not None:
                self._wake()

    def _wake(self):
        try:
            self._waiters.release()
        except RuntimeError:  # released by a concurrent set()
            pass

    def is_set(self) -> bool:
        return self.ready

    def wait(self, timeout: float | None = None) -> bool:
        if self.ready:
            return True
        lock = self._waiters
        if lock is None:
            with _GUARD_INIT:
                lock = self._waiters
                if lock is None:
                    lock = threading.Lock()
                    lock.acquire()
                    self._waiters = lock
        if self.ready:
            return True
        if lock.acquire(timeout=-1 if timeout is None else timeout):
            try:
                lock.release()  # let the other waiters through
            except RuntimeError:
                pass
            return True
        return self.ready


class Slot(Flag):
    """One value of one frame, where its producer left it, with cached copies elsewhere.

    ``where`` is ``"host"`` (NumPy data) or ``"device"`` (``wp.array`` data on the GPU role's
    device). The slot is its own :class:`Flag`, set (``ready``) once the value may be read
    (after the CUDA ``event``, if any): one object per value per frame, not two.
    """

    __slots__ = ("value", "where", "event", "external", "staged", "_host", "_device",
                 "_copy_lock")

    def __init__(self):
        self._waiters = None
        self.ready = False
        self.value = None
        self.where = HOST
        self.event = None
        self.external = False  # a device value made outside the executor's stream
        self.staged = None  # a download already under way (Transfers.stage_download)
        self._host = None
        self._device = None
        self._copy_lock = None  # made on the first download (most values are never downloaded)

    @classmethod
    def holding(cls, value, where=HOST) -> "Slot":
        """A slot set to ``value`` (``where`` it lives) from the start."""
        s = cls()
        s.set(value, where)
        return s

    def set(self, value, where, event=None):
        self.value, self.where, self.event = value, where, event
        self.ready = True  # (Flag.set, inline: once per value per frame)
        if self._waiters is not None:
            self._wake()

    def host(self, io: "Transfers", *, waited=None, alone: bool = False):
        """The value as host data, downloaded once (thread-safe).

        ``waited``: the event (:meth:`ready_event`) the caller already waited for on the
        host; the copy does not wait for it again. ``alone``: the caller is the value's only
        host reader (one task's, not the caller's nor a delay's): no other thread reads or
        drops it meanwhile, so no lock is made. (The GPU role attaches a staged download
        before it publishes the value: ``RoleRunner._set_devices``.)
        """
        if self.where == HOST:
            return self.value
        if alone:
            return self._download(io, waited)
        with self._guard():
            return self._download(io, waited)

    def _download(self, io: "Transfers", waited):
        """:meth:`host`'s copy, made once (the caller holds the copy lock, or reads alone)."""
        if self._host is None:
            staged = self.staged
            if staged is not None:
                # Views of the pool's buffers, lent for as long as the value lives.
                self._host = (io.unstage(staged, ready=waited is staged.event),)
                self.staged = None
            else:
                event = self.event
                self._host = (io.download(self.value, None if waited is event else event),)
        return self._host[0]

    def release_staged(self):
        """Drop the staged download not read (its frame is over, or a delay's ring let the
        slot go): its buffers go back to the pool once its copy is done (waited for here: a
        buffer is never lent again while a copy into it may run). Under the copy lock: a
        delay's reader of a later frame may be reading it."""
        if self.staged is None:
            return
        with self._guard():
            staged = self.staged
            if staged is not None:
                self.staged = None
                if staged.event is not None:
                    synchronize_event(staged.event)
                staged.close()

    def ready_event(self):
        """The CUDA event after which :meth:`host` copies without waiting: the staged
        download's, else the producer's (None: nothing to wait for)."""
        staged = self.staged
        return self.event if staged is None else staged.event

    def device(self, io: "Transfers", into=None):
        """The value on the GPU role's device, uploaded once. Only the GPU role uploads, one
        thread at a time (its token holder), so no lock.

        ``into(shape, dtype)``: a device buffer to upload an array leaf into, or None for a
        fresh one (see :meth:`Transfers.upload`).
        """
        if self.where == DEVICE:
            return self.value
        if self._device is None:
            self._device = (io.upload(self.value, into),)
        return self._device[0]

    def _guard(self) -> threading.Lock:
        lock = self._copy_lock
        if lock is None:
            with _GUARD_INIT:
                lock = self._copy_lock
                if lock is None:
                    lock = self._copy_lock = threading.Lock()
        return lock


class Ring:
    """Slots of one key for past frames (a delay's storage), indexed by absolute frame number.

    A frame's slot is reserved when the frame is submitted and filled when its producer runs.
    Frames before the first one, and frames whose slot was dropped (a cancelled frame), read
    the latest earlier slot that was filled, else the initial value. ``lock`` guards every
    access; the graph layer shares it with user threads (thesis §4.2).

    A slot may hold a staged download for a later frame's CPU reader (the executor stages
    a delay's value read on the host as it is produced): a slot dropped (aged out, replaced,
    reset, its frame cancelled) releases it (:meth:`Slot.release_staged`, outside the lock:
    it waits for the copy), so the pool's buffers go back and a device buffer the delay held
    is recycled only after the copy from it is done.
    """

    def __init__(self, slots: int, initial, lock=None):
        self.slots = int(slots)
        self.lock = lock if lock is not None else threading.RLock()
        self._initial = Slot.holding(initial)
        self._by_frame: dict[int, Slot] = {}
        self.last_aged = -1

    def reserve(self, frame: int, slot: Slot):
        with self.lock:
            self._by_frame[frame] = slot

    def get(self, frame: int) -> Slot:
        with self.lock:
            slot = self._by_frame.get(frame)
            if slot is not None:
                return slot
            earlier = [f for f, s in self._by_frame.items() if f < frame and s.ready]
            return self._by_frame[max(earlier)] if earlier else self._initial

    def put(self, frame: int, value, where=HOST):
        """Replace frame ``frame``'s value (a user write through the communication wrapper)."""
        with self.lock:
            old = self._by_frame.get(frame)
            self._by_frame[frame] = Slot.holding(value, where)
        _release_staged([old])

    @property
    def initial(self):
        """The value frames before the first one read."""
        return self._initial.value

    def set_initial(self, value):
        with self.lock:
            self._initial = Slot.holding(value)

    def reset(self):
        """Forget every frame: reads return the initial value again."""
        with self.lock:
            dropped = list(self._by_frame.values())
            self._by_frame.clear()
            self.last_aged = -1
        _release_staged(dropped)

    def age(self, frame: int):
        """Frame ``frame`` completed: it becomes the newest value; forget what no frame needs."""
        with self.lock:
            self.last_aged = max(self.last_aged, frame)
            keep_from = self.last_aged - self.slots
            dropped = [f for f in self._by_frame if f < keep_from]
            if not dropped:
                return
            dropped = [self._by_frame.pop(f) for f in dropped]
        _release_staged(dropped)

    def discard_pending(self, frame: int):
        """Frame ``frame`` was cancelled: drop its slot if its producer never ran; a slot kept
        (its producer ran) lets its staged download go (a later reader downloads it)."""
        with self.lock:
            slot = self._by_frame.get(frame)
            if slot is not None and not slot.ready:
                del self._by_frame[frame]
                return
        if slot is not None:
            slot.release_staged()

    def release_staged(self):
        """Let every slot's staged download go (the executor that staged them closes; the
        values stay, a later reader downloads them)."""
        with self.lock:
            slots = list(self._by_frame.values())
        _release_staged(slots)


def _release_staged(slots):
    """:meth:`Slot.release_staged` of each of ``slots`` (None skipped)."""
    for slot in slots:
        if slot is not None and slot.staged is not None:
            slot.release_staged()


__all__ = ["HOST", "DEVICE", "Flag", "Slot", "Ring"]
