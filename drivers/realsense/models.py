"""Depth stream data of the L515 and D435: resolutions, nominal intrinsics, depth units, ranges.

Nominal intrinsics are square-pixel focal lengths typical of shipped units (L515 70°×55° field
of view; D435 about 87°×58° at 16:9) with the principal point at the image centre. A real
device reports its own calibration, which the driver uses instead; the twin and tests use
these to make frames a real camera could produce.
"""

from __future__ import annotations

from dataclasses import dataclass

from climbd.daemon.contract.hardware import Intrinsics


@dataclass(frozen=True)
class DepthModel:
    """One camera model's depth stream: focal length (px) per resolution, fps, units, range (m)."""

    name: str
    product_line: str
    focal: dict[tuple[int, int], float]
    fps: tuple[int, ...]
    depth_unit: float
    depth_unit_fixed: bool
    min_range: float
    max_range: float
    presets: tuple[str, ...]

    @property
    def resolutions(self) -> list[tuple[int, int]]:
        """Depth stream resolutions (width, height), largest first."""
        return list(self.focal)

    def intrinsics(self, width: int, height: int) -> Intrinsics:
        """Nominal pinhole intrinsics of the ``width``×``height`` depth stream."""
        f = self.focal.get((width, height))
        if f is None:
            found = ", ".join(f"{w}x{h}" for w, h in self.focal)
            raise ValueError(f"{self.name}: no depth stream {width}x{height} (has {found})")
        return Intrinsics(width, height, f, f, (width - 1) / 2, (height - 1) / 2)


L515 = DepthModel(
    name="L515",
    product_line="L500",
    focal={(1024, 768): 731.0, (640, 480): 457.0, (320, 240): 228.5},
    fps=(30,),
    depth_unit=0.00025,
    depth_unit_fixed=True,
    min_range=0.25,
    max_range=9.0,
    presets=(
        "custom",
        "default",
        "no_ambient_light",
        "low_ambient_light",
        "max_range",
        "short_range",
    ),
)

D435 = DepthModel(
    name="D435",
    product_line="D400",
    focal={
        (1280, 720): 640.0,
        (848, 480): 424.0,
        (640, 480): 384.0,
        (640, 360): 320.0,
        (480, 270): 240.0,
        (424, 240): 212.0,
    },
    fps=(6, 15, 30, 60, 90),
    depth_unit=0.001,
    depth_unit_fixed=False,
    min_range=0.105,
    max_range=10.0,
    presets=(
        "custom",
        "default",
        "hand",
        "high_accuracy",
        "high_density",
        "medium_density",
        "remove_ir_pattern",
    ),
)

MODELS: dict[str, DepthModel] = {m.name: m for m in (L515, D435)}


def model(name: str) -> DepthModel:
    """The DepthModel called ``name`` (``L515`` or ``D435``); a clear error otherwise."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown RealSense model {name!r} (known: {', '.join(MODELS)})") from None
