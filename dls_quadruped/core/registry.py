"""A small named registry: the one pattern behind every "look it up by name" table of the package.

The simulator backends (``sim/registry.py``), the MPC cost kernels (``mpc/kernels.py``), the evaluation
scenarios (``eval/scenarios.py``) and the closed-loop controllers each keep one :class:`Registry`::

    GROUNDS = Registry("ground")
    GROUNDS.register("flat", flat_ground, "z = 0 everywhere")
    GROUNDS.get("flat")      # the registered object: flat_ground
    GROUNDS.get("moon")      # ValueError: unknown ground 'moon'; allowed: flat (z = 0 everywhere)

A registry holds objects (factories, values) in registration order, each with a one-line description for
``--help`` and error messages. It imports nothing of the package, so the module that validates a name
(a config) and the modules that register the objects never import each other.
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class Entry(Generic[T]):
    """A registered object: its name, the object, and a line for ``--help`` and error messages."""

    name: str
    obj: T
    description: str


class Registry(Generic[T]):
    """Objects of one kind by name, in registration order; unknown names fail with a line naming the allowed ones.

    Args:
        kind: what the names are names of (``"simulator backend"``), used in error messages.
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._entries: dict[str, Entry[T]] = {}

    def register(self, name: str, obj: T, description: str = "") -> T:
        """Make ``obj`` available as ``name``; returns ``obj`` (usable as a decorator's last step).

        Raises:
            ValueError: ``name`` is not a non-empty string, or is already registered.
        """
        if not isinstance(name, str) or not name:
            raise ValueError(f"{self.kind} name must be a non-empty string, got {name!r}")
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._entries[name] = Entry(name, obj, description)
        return obj

    def unregister(self, name: str) -> None:
        """Remove ``name`` (tests that register a temporary entry); unknown names are ignored."""
        self._entries.pop(name, None)

    def replace(self, name: str, obj: T) -> None:
        """Swap the object registered as ``name`` for ``obj``, keeping its description and place.

        Raises:
            ValueError: ``name`` is not registered (one line naming the allowed names).
        """
        entry = self._entries[self.check(name)]
        self._entries[name] = Entry(name, obj, entry.description)

    def check(self, name: Any) -> str:
        """``name`` if it is registered, else a one-line ``ValueError`` naming the allowed names."""
        if not isinstance(name, str) or name not in self._entries:
            raise ValueError(f"unknown {self.kind} {name!r}; allowed: {self.allowed()}")
        return name

    def get(self, name: Any) -> T:
        """The object registered as ``name``.

        Raises:
            ValueError: an unknown name (one line naming the allowed names, with their descriptions).
        """
        return self._entries[self.check(name)].obj

    def description(self, name: Any) -> str:
        """The line registered with ``name``."""
        return self._entries[self.check(name)].description

    def names(self) -> tuple[str, ...]:
        """The registered names, in registration order."""
        return tuple(self._entries)

    def entries(self) -> tuple[Entry[T], ...]:
        """The registered entries, in registration order."""
        return tuple(self._entries.values())

    def allowed(self) -> str:
        """The registered names, with their descriptions where they have one, for an error message."""
        return ", ".join(f"{e.name} ({e.description})" if e.description else e.name
                         for e in self._entries.values())

    def as_mapping(self) -> RegistryView[T]:
        """A live ``name -> object`` mapping view (for callers that index a plain table by name)."""
        return RegistryView(self)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(self._entries))

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, names={self.names()!r})"


class RegistryView(MutableMapping[str, T]):
    """``name -> object`` over a :class:`Registry`, live: it shows later registrations.

    Assigning to an existing name swaps its object (:meth:`Registry.replace`: what ``monkeypatch.setitem``
    does in tests); assigning a new name is refused (a new entry needs :meth:`Registry.register` and its
    description); deleting unregisters.
    """

    def __init__(self, registry: Registry[T]) -> None:
        self._registry = registry

    def __getitem__(self, name: str) -> T:
        if name not in self._registry:
            raise KeyError(name)
        return self._registry.get(name)

    def __setitem__(self, name: str, obj: T) -> None:
        if name not in self._registry:
            raise KeyError(f"{name!r} is not a registered {self._registry.kind}; register it with its description")
        self._registry.replace(name, obj)

    def __delitem__(self, name: str) -> None:
        if name not in self._registry:
            raise KeyError(name)
        self._registry.unregister(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._registry)

    def __len__(self) -> int:
        return len(self._registry)

    def __repr__(self) -> str:
        return repr(dict(self.items()))
