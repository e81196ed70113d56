"""The viewer page of ``monoavatar view``: one self-contained HTML file (three.js, the viewer's
script, the glb and the key-frame pictures all inside it) that opens from disk or is served on
the loopback address, and the key-frame atlas ``keyframes.jpg`` of an avatar folder.

The page's JavaScript ships in :mod:`monoavatar.io.viewer`: ``three.min.js`` is built from the
npm ``three`` package by ``tools/viewer/build.sh`` (MIT licence beside it), ``viewer.js`` is
ours. Nothing is fetched at run time.

``window.MONOAVATAR`` (the page's data, :attr:`ViewerPage.data`)::

    title        str
    summary      [str]       lines shown under the controls
    height_m     float       the avatar's height (frames the orbit camera)
    clips        [{name, world, root, times (N,), translations (N, 3) metres relative to the
                  root's rest position, rotations {joint: (N*4,) quaternions x y z w}}]
                 ``world`` clips are in the input camera's world (shown turned by ``upright``
                 and shifted by ``center`` in the orbit view); the others are Y-up already
    upright      (3, 3) rotation, world → Y-up
    center       (3,) metres, the Y-up point put at the orbit view's origin for world clips
    floor_y      metres, the rest pose's lowest point (put on the floor for the other clips)
    camera       {K (3, 3) px, R (3, 3), t (3,) metres, width, height} or null
    keyframes    {clip, indices (K,), cols, rows, tile (w, h) px} or null: the atlas's layout
    heat         {max_mm, mean_mm} or null: per glb vertex RGB in the ``heat`` block
"""

from __future__ import annotations

import base64
import http.server
import io
import json
import math
import threading
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from monoavatar.core.files import atomic_write_text

__all__ = ["ATLAS_PIXELS", "ATLAS_TILE_HEIGHT", "ViewerPage", "atlas_grid", "keyframe_atlas",
           "page_html", "serve_in_background", "serve_page", "split_atlas",
           "write_page"]  # fmt: skip

ATLAS_TILE_HEIGHT = 240
"""Height (pixels) of one key-frame in ``keyframes.jpg``, at most."""
ATLAS_PIXELS = 16_000_000
"""At most this many pixels in ``keyframes.jpg``: many frames get smaller tiles."""


def atlas_grid(count: int) -> tuple[int, int]:
    """(columns, rows) of an atlas of ``count`` tiles: as square as the count allows."""
    if count < 1:
        raise ValueError(f"an atlas needs at least one tile, got {count}")
    cols = math.ceil(math.sqrt(count))
    return cols, math.ceil(count / cols)


def keyframe_atlas(images: np.ndarray, tile_height: int = ATLAS_TILE_HEIGHT,
                   quality: int = 82) -> bytes:  # fmt: skip
    """(K, H, W, 3) uint8 frames → one JPEG of K tiles, row by row (:func:`atlas_grid`), each
    ``tile_height`` pixels high (less where the atlas would pass :data:`ATLAS_PIXELS`) with the
    frames' aspect ratio."""
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"expected (K, H, W, 3) uint8 frames, got {images.shape} {images.dtype}")
    k, h, w, _ = images.shape
    fitting = int(math.sqrt(ATLAS_PIXELS / (k * w / h)))
    th = max(16, min(tile_height, h, fitting))
    tw = max(1, round(w * th / h))
    cols, rows = atlas_grid(k)
    atlas = Image.new("RGB", (cols * tw, rows * th))
    for i, image in enumerate(images):
        tile = Image.fromarray(image).resize((tw, th), Image.Resampling.LANCZOS)
        atlas.paste(tile, ((i % cols) * tw, (i // cols) * th))
    out = io.BytesIO()
    atlas.save(out, format="JPEG", quality=quality)
    return out.getvalue()


def split_atlas(payload: bytes, count: int) -> np.ndarray:
    """The (count, h, w, 3) uint8 tiles of :func:`keyframe_atlas`'s JPEG."""
    atlas = np.asarray(Image.open(io.BytesIO(payload)).convert("RGB"))
    cols, rows = atlas_grid(count)
    th, tw = atlas.shape[0] // rows, atlas.shape[1] // cols
    return np.stack([atlas[(i // cols) * th:(i // cols + 1) * th, (i % cols) * tw:
                           (i % cols + 1) * tw] for i in range(count)])  # fmt: skip


@dataclass
class ViewerPage:
    """What the page shows: ``glb`` the avatar (glTF binary), ``data`` ``window.MONOAVATAR``
    (module docstring), ``atlas`` the key-frames' JPEG or None, ``heat`` (N, 3) uint8 per glb
    vertex or None."""

    glb: bytes
    data: dict[str, Any] = field(default_factory=dict)
    atlas: bytes | None = None
    heat: np.ndarray | None = None


def _asset(name: str) -> str:
    return resources.files("monoavatar.io").joinpath("viewer", name).read_text(encoding="utf-8")


def _block(block_id: str, kind: str, payload: bytes) -> str:
    text = base64.b64encode(payload).decode("ascii")
    return f'<script id="{block_id}" type="{kind}">{text}</script>\n'


def page_html(page: ViewerPage) -> str:
    """The whole page as one HTML string (a few MB: the glb and pictures are base64)."""
    data = json.dumps(page.data, separators=(",", ":")).replace("</", "<\\/")
    blocks = _block("data-glb", "application/octet-stream", page.glb)
    if page.atlas is not None:
        blocks += _block("data-atlas", "image/jpeg", page.atlas)
    if page.heat is not None:
        blocks += _block("data-heat", "application/octet-stream",
                         np.ascontiguousarray(page.heat, dtype=np.uint8).tobytes())  # fmt: skip
    scripts = (f"<script>window.MONOAVATAR = {data};</script>\n"
               f"<script>{_asset('three.min.js')}</script>\n"
               f"<script>{_asset('viewer.js')}</script>\n")  # fmt: skip
    return _asset("page.html").replace("<!--DATA-->", blocks + scripts)


def write_page(path: str | Path, page: ViewerPage) -> Path:
    """Write :func:`page_html` to ``path`` atomically; returns ``path``."""
    atomic_write_text(path, page_html(page))
    return Path(path)


def serve_page(html: str, port: int = 8000, host: str = "127.0.0.1"
               ) -> http.server.ThreadingHTTPServer:  # fmt: skip
    """An HTTP server (not yet serving: call ``serve_forever``) that answers ``/`` with
    ``html`` and anything else with 404. ``port`` 0 picks a free port (``server_address``)."""
    payload = html.encode("utf-8")

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
            if self.path.split("?")[0] not in ("/", "/index.html"):
                self.send_error(404)
                return
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(payload)))
            self.end_headers()
            self.wfile.write(payload)

        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002
            pass

    server = http.server.ThreadingHTTPServer((host, port), Handler)
    server.daemon_threads = True
    return server


def serve_in_background(html: str, port: int = 0) -> tuple[http.server.ThreadingHTTPServer,
                                                            threading.Thread]:  # fmt: skip
    """:func:`serve_page` on a daemon thread; returns the server (``shutdown()`` it) and the
    thread."""
    server = serve_page(html, port)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    return server, thread
