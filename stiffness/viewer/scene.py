"""The recorded scene: meshcat commands kept as a browser would hold them, in replay order.

Static pages embed it (:func:`stiffness.viewer.page.render_page`); the live server replays it
to every browser that joins.
"""

from __future__ import annotations


class SceneStore:
    """The scene as a browser would hold it: meshcat commands, latest per node and kind.

    Replayed in a deterministic order (a node's object, its children, its properties, its
    transform; the animation last), for static pages and for browsers joining a live server.
    Commands are msgpack-packed bytes exactly as meshcat sends them.
    """

    def __init__(self) -> None:
        self.root: dict = self._node()
        self.animation: bytes | None = None

    @staticmethod
    def _node() -> dict:
        return {"object": None, "properties": {}, "transform": None, "children": {}}

    def _find(self, path: str) -> dict:
        """The node at ``path``, created with its parents where missing."""
        node = self.root
        for name in [p for p in path.split("/") if p]:
            if name not in node["children"]:
                node["children"][name] = self._node()
            node = node["children"][name]
        return node

    def _existing(self, path: str) -> dict | None:
        """The node at ``path``, or None where it (or a parent) is missing."""
        node = self.root
        for name in [p for p in path.split("/") if p]:
            if name not in node["children"]:
                return None
            node = node["children"][name]
        return node

    def apply(self, kind: str, path: str, packed: bytes, key: str | None = None) -> None:
        """Record one command (``kind`` = meshcat command type, ``key`` = property name)."""
        if kind == "set_animation":
            self.animation = packed
            return
        if kind == "delete":
            names = [p for p in path.split("/") if p]
            if not names:
                self.root, self.animation = self._node(), None
                return
            parent = self._existing("/".join(names[:-1]))
            if parent is not None:
                parent["children"].pop(names[-1], None)
            return
        node = self._find(path)
        if kind == "set_object":
            node["object"] = packed
        elif kind == "set_transform":
            node["transform"] = packed
        elif kind == "set_property":
            node["properties"][key or ""] = packed

    def commands(self) -> list[bytes]:
        """Every stored command in replay order."""
        out: list[bytes] = []

        def walk(node: dict) -> None:
            if node["object"] is not None:
                out.append(node["object"])
            for child in node["children"].values():
                walk(child)
            out.extend(node["properties"].values())
            if node["transform"] is not None:
                out.append(node["transform"])

        walk(self.root)
        if self.animation is not None:
            out.append(self.animation)
        return out
