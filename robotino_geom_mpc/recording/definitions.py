"""Message types of a recording: the ``ros2msg`` definitions a bag stores (rosbags' typesys) and rclpy classes."""

from __future__ import annotations

import importlib
from functools import lru_cache
from pathlib import Path

from rosbags.typesys import Stores, TypesysError, get_typestore, get_types_from_msg
from rosbags.typesys.store import Typestore

from robotino_geom_mpc.recording.bagfile import BagError

__all__ = ["message_definition", "message_class"]


def _split_type(type_name: str) -> tuple[str, str, str]:
    parts = type_name.split("/")
    if len(parts) == 2:
        return parts[0], "msg", parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise BagError(f"message type '{type_name}' is not of the form pkg/msg/Type")


@lru_cache(maxsize=1)
def _typestore() -> Typestore:
    return get_typestore(Stores.ROS2_JAZZY)


def _register_installed(store: Typestore, type_name: str) -> None:
    """Add a type the Jazzy store lacks from its installed .msg (``<prefix>/share/<pkg>/msg/<Type>.msg``)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    package, folder, base = _split_type(type_name)
    try:
        path = Path(get_package_share_directory(package)) / folder / f"{base}.msg"
        text = path.read_text()
    except (PackageNotFoundError, LookupError, ValueError, OSError):
        raise BagError(f"no message definition for '{type_name}' (neither in rosbags' ROS 2 Jazzy types nor "
                       "installed in the ament index, AMENT_PREFIX_PATH)") from None
    try:
        store.register(get_types_from_msg(text, f"{package}/{folder}/{base}"))
    except TypesysError as exc:
        raise BagError(f"cannot parse {path}: {exc}") from None


def message_definition(type_name: str) -> str:
    r"""The full ``ros2msg`` text of a type with its dependencies, as a rosbag2 schema holds it.

    rosbags' `Typestore.generate_msgdef` writes the type's fields, then each
    dependency after ``"=" * 80 + "\\nMSG: pkg/Type\\n"`` (the layout of
    rosbag2's LocalMessageDefinitionSource, without the comments of the
    .msg files). Types come from rosbags' ROS 2 Jazzy store; a type it lacks
    is parsed from its installed .msg file (its dependencies must be in the store).

    Raises
    ------
    BagError
        If the type or one of its dependencies is unknown.
    """
    store = _typestore()
    package, folder, base = _split_type(type_name)
    full = f"{package}/{folder}/{base}"
    if full not in store.fielddefs:
        _register_installed(store, full)
    try:
        text, _ = store.generate_msgdef(full, ros_version=2)
    except TypesysError as exc:  # a dependency the store lacks
        raise BagError(f"cannot write the message definition of '{type_name}': {exc}") from None
    return text


def message_class(type_name: str) -> type:
    """The Python class of a ROS message type ``pkg/msg/Type`` (imported from ``pkg.msg``).

    Raises
    ------
    BagError
        If the package or the type cannot be imported.
    """
    package, folder, base = _split_type(type_name)
    try:
        return getattr(importlib.import_module(f"{package}.{folder}"), base)
    except (ImportError, AttributeError):
        raise BagError(f"message type '{type_name}' is not installed (no Python module {package}.{folder})") from None
