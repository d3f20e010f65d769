"""Writes the target scene's textures and meshes into models/ (run: python -m alight.models.textures).

target_pattern.png: the landing pattern (alight.systems.perception.pattern) on the platform;
target_ground.png: a 32 m ground tile (asphalt, grass, lane marks) with look-alike squares that the
detector must reject (plain tiles, ring-only, cross-only, helipad H, checkerboard, nested squares,
a diagonal cross); target_pattern.obj and target_ground.obj: textured squares; rgbd_ground.png and
rgbd_ground.obj: the field the forward VIO camera sees (issue 8): gravel, asphalt and grass with
centimetre-scale detail well above the camera's pixel noise, which target_ground's smooth 3 cm
texels lack (the rendered VIO found no corners within its depth range there). The files are
committed; tests/test_target_vehicle.py checks that they match this generator.
"""
from pathlib import Path

import cv2
import numpy as np

from alight.models import MODELS_DIR

GROUND_TILE = 32.0       # m per texture repeat
GROUND_PIXELS = 1024
GROUND_EXTENT = 800.0    # m, side of the ground (25 x 25 tiles)
PATTERN_PIXELS = 2048
RGBD_GROUND_TILE = 16.0  # m per texture repeat: 1.6 cm texels
RGBD_GROUND_EXTENT = 400.0


def ground_texture(seed: int = 5) -> np.ndarray:
    """The ground tile (BGR uint8), deterministic."""
    rng = np.random.default_rng(seed)
    n = GROUND_PIXELS
    m_per_px = GROUND_TILE / n
    blobs = _periodic_blur(rng.normal(0, 1, (n, n)), 20)
    blobs /= blobs.std()
    grey = 105 + 22 * blobs + 3 * _periodic_blur(rng.normal(0, 1, (n, n)), 1.5) / 0.19
    image = np.repeat(grey[..., None], 3, axis=2)
    grass = _periodic_blur(rng.normal(0, 1, (n, n)), 40)
    grass = np.clip((grass / grass.std() - 0.8) * 2, 0, 1)[..., None]
    image = image * (1 - grass) + grass * np.array([60, 120, 85]) * (0.8 + 0.2 * blobs[..., None])
    image = np.clip(image, 0, 255).astype(np.uint8)

    def px(metres):
        return int(round(metres / m_per_px))

    for row in (0.2, 0.7):  # lane marks
        y = px(row * GROUND_TILE)
        for x0 in range(0, n, px(6.0)):
            cv2.rectangle(image, (x0, y), (x0 + px(3.0), y + px(0.15)), (225, 225, 225), -1)
    lookalikes = [_plain, _ring_only, _cross_only, _helipad, _checker, _nested, _diagonal,
                  _plain, _ring_only, _cross_only]
    for i, draw in enumerate(lookalikes):
        side = rng.uniform(1.0, 1.6)
        s = px(side) // 2 * 2
        tile = draw(s)
        centre = np.array([(i % 5 + 0.5) * n / 5, (i // 5 + 0.3 + 0.4 * (i % 2)) * n / 2])
        centre += rng.uniform(-0.05, 0.05, 2) * n
        angle = rng.uniform(0, 90)
        _paste_rotated(image, tile, centre, angle)
    return image


def rgbd_ground_texture(seed: int = 11) -> np.ndarray:
    """The VIO camera's ground tile (BGR uint8), deterministic: gravel (1.6 and 6 cm grains) on
    patches of asphalt and grass (0.5 m), bright enough under the renderer's light that the
    grain contrast (about 25 grey levels) stands well above 2 grey levels of pixel noise."""
    rng = np.random.default_rng(seed)
    n = GROUND_PIXELS

    def layer(sigma):
        return _unit_noise(rng, n, sigma)

    patches = layer(30)
    grey = 150 + 20 * patches + 18 * layer(4) + 18 * layer(1)
    image = np.repeat(grey[..., None], 3, axis=2)
    grass = np.clip((layer(60) - 0.6) * 2, 0, 1)[..., None]
    image = image * (1 - grass) + grass * (image * [0.55, 1.0, 0.7])
    return np.clip(image, 0, 255).astype(np.uint8)


def field_ground_texture(seed: int = 13) -> np.ndarray:
    """The ground tile of a scene where both cameras render (BGR uint8, 2x the target ground's
    pixels, deterministic): the target ground (its asphalt, grass, lane marks and look-alikes)
    with the VIO ground's grain (1.6 and 6 cm) on top, so the forward camera finds corners
    within its depth range where the down camera finds the landing field."""
    rng = np.random.default_rng(seed)
    n = 2 * GROUND_PIXELS
    base = cv2.resize(ground_texture(), (n, n), interpolation=cv2.INTER_LINEAR).astype(float)
    grain = 16 * _unit_noise(rng, n, 4) + 16 * _unit_noise(rng, n, 1)
    return np.clip(base + grain[..., None], 0, 255).astype(np.uint8)


def _unit_noise(rng, n: int, sigma: float) -> np.ndarray:
    """An n x n tile of Gaussian noise blurred over `sigma` px (wrapping), scaled to unit std."""
    noise = _periodic_blur(rng.normal(0, 1, (n, n)), sigma)
    return noise / noise.std()


def _periodic_blur(noise: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur with wrap-around (the tile repeats seamlessly)."""
    f = np.fft.fftfreq(noise.shape[0])
    g = np.exp(-2 * (np.pi * sigma) ** 2 * (f[:, None] ** 2 + f[None, :] ** 2))
    return np.real(np.fft.ifft2(np.fft.fft2(noise) * g))


def _square(s, black_band):
    tile = np.full((s, s), 235, np.uint8)
    b = max(1, int(round(s * black_band)))
    tile[:b] = tile[-b:] = 25
    tile[:, :b] = tile[:, -b:] = 25
    return tile


def _plain(s):
    return _square(s, 0.07)


def _ring_only(s):
    tile = _square(s, 0.07)
    cv2.circle(tile, (s // 2, s // 2), int(s * 0.37), 25, max(1, int(s * 0.09)))
    return tile


def _cross_only(s):
    tile = _square(s, 0.07)
    w = max(1, int(s * 0.045))
    tile[s // 2 - w:s // 2 + w, int(s * 0.15):int(s * 0.85)] = 25
    tile[int(s * 0.15):int(s * 0.85), s // 2 - w:s // 2 + w] = 25
    return tile


def _helipad(s):
    tile = _square(s, 0.07)
    w = max(1, int(s * 0.08))
    tile[int(s * 0.25):int(s * 0.75), int(s * 0.3):int(s * 0.3) + w] = 25
    tile[int(s * 0.25):int(s * 0.75), int(s * 0.7) - w:int(s * 0.7)] = 25
    tile[s // 2 - w // 2:s // 2 + w // 2 + 1, int(s * 0.3):int(s * 0.7)] = 25
    return tile


def _checker(s):
    tile = np.full((s, s), 235, np.uint8)
    tile[:s // 2, :s // 2] = tile[s // 2:, s // 2:] = 25
    return tile


def _nested(s):
    tile = np.full((s, s), 25, np.uint8)
    for frac, value in ((0.12, 235), (0.25, 25), (0.38, 235)):
        b = int(s * frac)
        tile[b:s - b, b:s - b] = value
    return tile


def _diagonal(s):
    tile = _square(s, 0.07)
    w = max(1, int(s * 0.09))
    cv2.line(tile, (int(s * 0.2), int(s * 0.2)), (int(s * 0.8), int(s * 0.8)), 25, w)
    cv2.line(tile, (int(s * 0.8), int(s * 0.2)), (int(s * 0.2), int(s * 0.8)), 25, w)
    return tile


def _paste_rotated(image, tile, centre, angle_deg):
    s = tile.shape[0]
    M = cv2.getRotationMatrix2D((s / 2, s / 2), angle_deg, 1.0)
    M[:, 2] += centre - s / 2
    h, w = image.shape[:2]
    warped = cv2.warpAffine(tile, M, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
    mask = cv2.warpAffine(np.full_like(tile, 255), M, (w, h), flags=cv2.INTER_LINEAR,
                          borderValue=0).astype(np.float32)[..., None] / 255
    image[:] = (image * (1 - mask) + warped[..., None] * mask).astype(np.uint8)


def textured_grid_obj(name: str, half_side: float, tiles: int, z: float) -> tuple[str, str]:
    """OBJ and MTL text of a square in the z = `z` plane (normal +z) made of tiles x tiles quads,
    each carrying the whole texture (RenderEngineVtk clamps texture coordinates outside [0, 1], so
    a repeating texture needs one quad per repeat)."""
    edges = np.linspace(-half_side, half_side, tiles + 1)
    lines = [f"mtllib {name}.mtl"]
    lines += [f"v {x:.4f} {y:.4f} {z}" for y in edges for x in edges]
    lines += ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1", "vn 0 0 1", f"usemtl {name}"]
    for j in range(tiles):
        for i in range(tiles):
            a = j * (tiles + 1) + i + 1
            b, c, d = a + 1, a + tiles + 2, a + tiles + 1
            lines += [f"f {a}/1/1 {b}/2/1 {c}/3/1", f"f {a}/1/1 {c}/3/1 {d}/4/1"]
    mtl = (f"newmtl {name}\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\n"
           f"map_Kd {name}.png\n")
    return "\n".join(lines) + "\n", mtl


def generated_files() -> dict[str, bytes]:
    """Every generated file's name and content."""
    from alight.systems.perception.pattern import Pattern, load_pattern_params
    pattern = Pattern(load_pattern_params())
    files = {}
    template = pattern.template(PATTERN_PIXELS)
    files["target_pattern.png"] = cv2.imencode(".png", cv2.cvtColor(template, cv2.COLOR_GRAY2BGR))[1] \
        .tobytes()
    files["target_ground.png"] = cv2.imencode(".png", ground_texture())[1].tobytes()
    files["rgbd_ground.png"] = cv2.imencode(".png", rgbd_ground_texture())[1].tobytes()
    files["field_ground.png"] = cv2.imencode(".png", field_ground_texture())[1].tobytes()
    tiles = int(round(GROUND_EXTENT / GROUND_TILE))
    rgbd_tiles = int(round(RGBD_GROUND_EXTENT / RGBD_GROUND_TILE))
    for name, half_side, n in (("target_pattern", pattern.params.side / 2, 1),
                               ("target_ground", tiles * GROUND_TILE / 2, tiles),
                               ("field_ground", tiles * GROUND_TILE / 2, tiles),
                               ("rgbd_ground", rgbd_tiles * RGBD_GROUND_TILE / 2, rgbd_tiles)):
        obj, mtl = textured_grid_obj(name, half_side, n, 0.0)
        files[f"{name}.obj"], files[f"{name}.mtl"] = obj.encode(), mtl.encode()
    return files


def main(directory: Path = MODELS_DIR) -> None:
    for name, content in generated_files().items():
        (Path(directory) / name).write_bytes(content)
        print(f"wrote {Path(directory) / name}")


if __name__ == "__main__":
    main()
