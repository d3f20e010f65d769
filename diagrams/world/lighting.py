"""The light of the rendered scene (issue 20): a sun whose elevation, azimuth and intensity are
drawn per run from the scenario's seed, and a sky fill from above; or Drake's default headlight
(`kind: camera`, the scene before issue 20's lighting). Both cameras render in the one renderer
that `add_renderer` adds, so they see the same light. Nothing here reads the wall clock: the same
scenario and seed give the same light."""
import dataclasses as dc

import numpy as np
from pydrake.geometry import LightParameter, MakeRenderEngineVtk, RenderEngineVtkParams, Rgba

from alight.systems.params import bounded, choice

RENDERER = "alight_vtk"


@dc.dataclass
class LightingParams:
    """Scenario key `vehicle.lighting`. Each range [lo, hi] is drawn uniformly per run: the sun's
    elevation, the share of the light on level ground that comes from the sky, and the level
    ground's brightness that the cameras' auto-exposure leaves, relative to Drake's headlight
    facing the ground (what the scene had before)."""
    kind: str = choice("sun", "camera")
    sun_elevation: list[float] = bounded([25.0, 75.0], 5.0, 90.0, "deg")
    sky_share: list[float] = bounded([0.2, 0.45], 0.0, 1.0)
    exposure: list[float] = bounded([0.8, 1.1], 0.1, 3.0)
    # Set from the scenario's random_seed (diagrams/scenario.py `vehicle_config`).
    seed: int = 0


@dc.dataclass(frozen=True)
class Light:
    """One run's drawn light: the sun's elevation and azimuth [deg] (azimuth from x_W,
    counter-clockwise, toward the sun) and the intensities."""
    sun_elevation: float
    sun_azimuth: float
    sun_intensity: float
    sky_intensity: float

    def direction(self) -> np.ndarray:
        """The sunlight's direction of travel in W (from the sun toward the ground)."""
        el, az = np.radians(self.sun_elevation), np.radians(self.sun_azimuth)
        return -np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])

    def ground_irradiance(self) -> float:
        """The light on level ground, relative to Drake's headlight facing it (1)."""
        return self.sun_intensity * np.sin(np.radians(self.sun_elevation)) + self.sky_intensity


def draw_light(params: LightingParams) -> Light:
    """The light of `params.seed` (a stream of its own: it moves no other random source)."""
    rng = np.random.default_rng([params.seed, 0x11647])
    elevation = float(rng.uniform(*params.sun_elevation))
    azimuth = float(rng.uniform(0.0, 360.0))
    sky = float(rng.uniform(*params.sky_share))
    ground = float(rng.uniform(*params.exposure))
    return Light(sun_elevation=elevation, sun_azimuth=azimuth,
                 sun_intensity=float(ground * (1.0 - sky) / np.sin(np.radians(elevation))),
                 sky_intensity=ground * sky)


def render_engine_params(params: LightingParams, backend: str = "") -> RenderEngineVtkParams:
    """RenderEngineVtk's parameters for `params`: the drawn sun and sky as world-fixed
    directional lights, or (`kind: camera`) none, i.e. Drake's headlight."""
    if params.kind == "camera":
        return RenderEngineVtkParams(backend=backend)
    light = draw_light(params)
    sun = LightParameter(type="directional", frame="world", direction=light.direction(),
                         intensity=light.sun_intensity, color=Rgba(1.0, 0.97, 0.92, 1.0))
    sky = LightParameter(type="directional", frame="world", direction=[0.0, 0.0, -1.0],
                         intensity=light.sky_intensity, color=Rgba(0.85, 0.9, 1.0, 1.0))
    return RenderEngineVtkParams(backend=backend, lights=[sun, sky])


def add_renderer(scene_graph, params: LightingParams, backend: str = "") -> None:
    """Adds the scene's VTK renderer (headless) under RENDERER, lit by `params`, unless the
    scene graph has it."""
    if not scene_graph.HasRenderer(RENDERER):
        scene_graph.AddRenderer(RENDERER, MakeRenderEngineVtk(render_engine_params(params,
                                                                                  backend)))
