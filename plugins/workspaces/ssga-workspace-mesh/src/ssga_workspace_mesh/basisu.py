"""Basis Universal textures in glTF files, decoded before trimesh reads the file.

Habitat's scenes (HM3D's ``*.basis.glb``, MP3D's) store their textures compressed with
Basis Universal, which no image library reads, so trimesh skips them and every
surface would render in its flat base colour. Two glTF extensions point at such images:

* ``KHR_texture_basisu``: the standard one; the image is a KTX2 file (``image/ktx2``).
* ``GOOGLE_texture_basis``: the older one Habitat's converters write (HM3D); the image
  is a bare ``.basis`` file (``image/x-basis``).

Either way the texture's image index lives in ``textures[i].extensions.<ext>.source``
instead of ``textures[i].source``. :func:`with_decoded_textures` decodes every such
image with Binomial's transcoder (the ``opengl_basisu`` package: KTX2 and ``.basis``,
ETC1S and UASTC, to RGBA8) and hands back the file with plain images in their place and
plain ``source`` references, which trimesh then loads like any other textured glTF.

Orientation: a ``.basis`` header can say its image was stored bottom row first (the
encoder's ``-y_flip``, which Habitat's Magnum-based tools use because Magnum's images
are bottom-up); such images are flipped back, so that every decoded image is top row
first, as glTF's texture coordinates expect. KTX2 images in glTF are top row first by
the extension's rules.
"""

from __future__ import annotations

import base64
import io
import json
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np
from PIL import Image

from ssga_core import InputError

BASIS_EXTENSIONS = ("KHR_texture_basisu", "GOOGLE_texture_basis")
"""glTF texture extensions whose ``source`` is a Basis Universal image."""

BASIS_MIME_TYPES = frozenset({"image/ktx2", "image/x-basis", "image/basis"})
BASIS_SUFFIXES = (".ktx2", ".basis")

DECODER_HINT = "pip install 'opengl_basisu>=0.1.0a2'"
"""What to install when the decoder is missing."""

_GLB_MAGIC = b"glTF"
_JSON_CHUNK, _BIN_CHUNK = 0x4E4F534A, 0x004E4942
# The decoded images are handed to trimesh in memory only, so an uncompressed format
# costs nothing on disk: BMP writes and reads a 2048 x 2048 texture in about 10 ms each,
# PNG (even at compression level 0) takes 0.3 s to write.
_DECODED_MIME, _DECODED_FORMAT = "image/bmp", "BMP"


def with_decoded_textures(path: Path) -> tuple[bytes, str] | None:
    """The glTF/GLB file at ``path`` with its Basis Universal images decoded, or None if it has none.

    Returns:
        The rewritten file and its type for trimesh (``"glb"`` or ``"gltf"``), or None
        when the file has no Basis images (or is not a glTF file it can parse: then
        trimesh reports what is wrong with it).

    Raises:
        InputError: the decoder is not installed, or an image cannot be decoded; one
            line naming the file.
    """
    suffix = path.suffix.lower()
    if suffix not in (".glb", ".gltf"):
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None  # trimesh's attempt reports it
    parsed = split_glb(data) if suffix == ".glb" else _read_gltf(data)
    if parsed is None:
        return None
    gltf, binary = parsed
    basis = _basis_images(gltf)
    if not basis:
        return None
    first = gltf["images"][min(basis)]
    decode = _transcoder(f"{path}: its textures are Basis Universal ({first.get('mimeType') or first.get('uri')})")
    # In a GLB whose buffer 0 is its binary chunk, decoded images are appended to that
    # chunk in buffer views of their own (the views already there keep their offsets);
    # otherwise they go inline, as data URIs.
    embed = suffix == ".glb" and not (gltf.get("buffers") or [{}])[0].get("uri")
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    appended: list[bytes] = []
    for index in sorted(basis):
        image = gltf["images"][index]
        encoded = io.BytesIO()
        Image.fromarray(decode(_image_bytes(path, gltf, binary, image), f"{path}: image {index}")).save(encoded, _DECODED_FORMAT)
        blob = encoded.getvalue()
        decoded: dict[str, Any] = {"mimeType": _DECODED_MIME, **({"name": image["name"]} if "name" in image else {})}
        if embed:
            views = gltf.setdefault("bufferViews", [])
            views.append({"buffer": 0, "byteOffset": len(binary) + sum(map(len, appended)), "byteLength": len(blob)})
            decoded["bufferView"] = len(views) - 1
            appended.append(blob + b"\0" * (-len(blob) % 4))
        else:
            decoded["uri"] = f"data:{_DECODED_MIME};base64,{base64.b64encode(blob).decode('ascii')}"
        gltf["images"][index] = decoded
    _use_plain_sources(gltf)
    if not embed:
        return (join_glb(gltf, binary) if suffix == ".glb" else json.dumps(gltf).encode()), suffix.lstrip(".")
    binary += b"".join(appended)
    gltf["buffers"] = gltf.get("buffers") or [{}]
    gltf["buffers"][0]["byteLength"] = len(binary)
    return join_glb(gltf, binary), "glb"


def _transcoder(what: str) -> Callable[[bytes, str], np.ndarray]:
    """A function decoding one KTX2 or ``.basis`` file to ``(H, W, 3)`` uint8 RGB, top row first.

    Raises:
        InputError: the decoder is not installed (``what`` says what needs it).
    """
    try:
        import opengl_basisu
    except ImportError:
        raise InputError(f"{what}, which needs a decoder: {DECODER_HINT}") from None

    def decode(data: bytes, name: str) -> np.ndarray:
        try:
            texture = opengl_basisu.open(bytes(data))
            rgba = np.asarray(texture.transcode(opengl_basisu.Target.RGBA8).data)
        except (opengl_basisu.BasisuError, ValueError, IndexError) as exc:
            raise InputError(f"{name}: cannot decode its Basis Universal texture ({' '.join(str(exc).split())})") from None
        if texture.y_flipped:
            rgba = rgba[::-1]
        return np.ascontiguousarray(rgba[..., :3])

    return decode


def _basis_images(gltf: dict[str, Any]) -> set[int]:
    """Indices of the images that are Basis Universal: by their MIME type or file suffix, or
    because a texture's Basis extension points at them."""
    images = gltf.get("images")
    if not isinstance(images, list):
        return set()
    found = set()
    for index, image in enumerate(images):
        if not isinstance(image, dict):
            continue
        uri = str(image.get("uri", ""))
        if image.get("mimeType") in BASIS_MIME_TYPES or (not uri.startswith("data:") and uri.lower().endswith(BASIS_SUFFIXES)):
            found.add(index)
    for texture in gltf.get("textures") or []:
        source = _basis_source(texture)
        if isinstance(source, int) and 0 <= source < len(images):
            found.add(source)
    return found


def _basis_source(texture: Any) -> Any:
    extensions = texture.get("extensions") if isinstance(texture, dict) else None
    for name in BASIS_EXTENSIONS:
        if isinstance(extensions, dict) and isinstance(extensions.get(name), dict) and "source" in extensions[name]:
            return extensions[name]["source"]
    return None


def _use_plain_sources(gltf: dict[str, Any]) -> None:
    """Point every texture at its (now decoded) Basis image and drop the extensions."""
    for texture in gltf.get("textures") or []:
        source = _basis_source(texture)
        if source is None:
            continue
        texture["source"] = source  # preferred over a fallback PNG/JPEG source: it is what Habitat shows
        for name in BASIS_EXTENSIONS:
            texture["extensions"].pop(name, None)
        if not texture["extensions"]:
            del texture["extensions"]
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in gltf:
            gltf[key] = [e for e in gltf[key] if e not in BASIS_EXTENSIONS]
            if not gltf[key]:
                del gltf[key]


def _image_bytes(path: Path, gltf: dict[str, Any], binary: bytes, image: dict[str, Any]) -> bytes:
    if "bufferView" in image:
        try:
            view = gltf["bufferViews"][image["bufferView"]]
            start = int(view.get("byteOffset", 0))
            return binary[start : start + int(view["byteLength"])]
        except (LookupError, TypeError, ValueError):
            raise InputError(f"{path}: an image's bufferView is not in the file") from None
    uri = str(image.get("uri", ""))
    if uri.startswith("data:"):
        try:
            return base64.b64decode(uri.split(",", 1)[-1], validate=True)
        except ValueError:
            raise InputError(f"{path}: an image's data URI is not base64") from None
    file = path.parent / unquote(uri)
    if not file.is_file():
        raise InputError(f"{file}: no such texture file (named by {path})")
    return file.read_bytes()


def _read_gltf(data: bytes) -> tuple[dict[str, Any], bytes] | None:
    try:
        gltf = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    return (gltf, b"") if isinstance(gltf, dict) else None


def split_glb(data: bytes) -> tuple[dict[str, Any], bytes] | None:
    """The JSON and the binary chunk of a GLB file; None if it is not one."""
    if len(data) < 20 or data[:4] != _GLB_MAGIC:
        return None
    length, kind = struct.unpack_from("<II", data, 12)
    if kind != _JSON_CHUNK or 20 + length > len(data):
        return None
    try:
        gltf = json.loads(data[20 : 20 + length])
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(gltf, dict):
        return None
    start = 20 + length
    binary = b""
    if start + 8 <= len(data):
        size, kind = struct.unpack_from("<II", data, start)
        if kind == _BIN_CHUNK:
            binary = data[start + 8 : start + 8 + size]
    return gltf, binary


def join_glb(gltf: dict[str, Any], binary: bytes) -> bytes:
    """A GLB file of a glTF JSON document and its binary chunk (buffer 0)."""
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned; JSON pads with spaces
    body = struct.pack("<II", len(text), _JSON_CHUNK) + text + struct.pack("<II", len(binary), _BIN_CHUNK) + binary
    return _GLB_MAGIC + struct.pack("<II", 2, 12 + len(body)) + body
