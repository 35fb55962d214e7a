"""Cameras and stages by name: what ``kind`` in the ``[camera]`` and ``[stage]`` tables names.

As in python-microscope's device configuration, the configuration names the driver's class
(``kind = "AravisCamera"``), its full dotted path (``"mylab.cameras.LineCamera"``, for a driver kept
outside this repository) or one of the short names a driver also answers to (``"aravis"``: the
names the configuration contract has always taken). A driver registers itself where it is
defined, with :meth:`Registry.register` on its class, so a new camera or stage is one module in
drivers/camera/ (or drivers/stage/) and its tests: neither config.py nor factory.py lists drivers.
A hardware driver builds itself from its table (``from_config``); a simulated one is built by the
virtual rig (drivers/factory.py), since what it shows or moves is the rig's.

The package's modules are imported on the first lookup. One whose import fails (a library it needs
is missing) is kept with its error, and the error for a name nobody registered lists both what is
known and what could not be loaded, so a missing dependency is not reported as a misspelt name.
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from typing import Callable, TypeVar

T = TypeVar("T", bound=type)


@dataclass(frozen=True)
class Driver:
    """One registered class and the names it answers to."""

    cls: type
    aliases: tuple[str, ...]
    simulated: bool  # built by the virtual rig (drivers/factory.py), not from its table alone

    @property
    def name(self) -> str:
        """What ``kind`` reads after validation: the first short name (the contract's spelling, which
        the rest of the daemon compares against), else the class name."""
        return self.aliases[0] if self.aliases else self.cls.__name__

    def names(self) -> tuple[str, ...]:
        return (*self.aliases, self.cls.__name__, f"{self.cls.__module__}.{self.cls.__qualname__}")


class Registry:
    """The drivers of one kind of device (``what``: "camera", "stage"), found in ``package``."""

    def __init__(self, what: str, package: str) -> None:
        self.what = what
        self.package = package
        self._by_name: dict[str, Driver] = {}
        self._unloaded: dict[str, str] = {}  # module → why its import failed
        self._discovered = False

    def register(self, *aliases: str, simulated: bool = False) -> Callable[[T], T]:
        """Class decorator: the class answers to its name, its dotted path and ``aliases``. A name
        another class holds already is an error at import, not a driver silently shadowed."""
        def add(cls: T) -> T:
            driver = Driver(cls, tuple(aliases), simulated)
            for name in driver.names():
                held = self._by_name.get(name)
                if held is not None and held.names()[-1] != driver.names()[-1]:  # (a module imported again: itself)
                    raise ValueError(f"{self.what} name {name!r} is {held.names()[-1]}'s")
            for name in driver.names():
                self._by_name[name] = driver
            return cls
        return add

    def resolve(self, name: str) -> Driver:
        """The driver ``name`` names; LookupError (its message lists the known names) when none does."""
        self._discover()
        driver = self._by_name.get(name)
        if driver is None and "." in name:  # a driver outside the package: importing it registers it
            module = name.rpartition(".")[0]
            try:
                importlib.import_module(module)
            except ImportError as exc:
                raise LookupError(f"{self.what} {name!r}: cannot import {module} ({exc})") from None
            driver = self._by_name.get(name)
        if driver is None:
            raise LookupError(self._unknown(name))
        return driver

    def known(self) -> list[Driver]:
        """Every registered driver once, by name."""
        self._discover()
        unique = {id(driver.cls): driver for driver in self._by_name.values()}
        return sorted(unique.values(), key=lambda driver: driver.name)

    def _discover(self) -> None:
        if self._discovered:
            return
        self._discovered = True
        package = importlib.import_module(self.package)
        for module in pkgutil.iter_modules(package.__path__):
            try:
                importlib.import_module(f"{self.package}.{module.name}")
            except ImportError as exc:
                self._unloaded[f"{self.package}.{module.name}"] = str(exc)

    def _unknown(self, name: str) -> str:
        known = ", ".join(f"{driver.name} ({driver.cls.__name__})" for driver in self.known())
        message = f"unknown {self.what} {name!r}; known: {known or 'none'}"
        if self._unloaded:
            message += "; not loaded: " + ", ".join(f"{module} ({why})" for module, why in self._unloaded.items())
        return message


cameras = Registry("camera", "graytrack.drivers.camera")
stages = Registry("stage", "graytrack.drivers.stage")
