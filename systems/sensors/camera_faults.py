"""A sensor-side fault injector for a camera port (simulation only): during each blackout window
the frames are replaced by empty, invalid `CameraFrame`s, as when a camera stops or its cable comes
loose. Not onboard code: consumers must cope with the invalid frames."""
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import CameraFrame


class CameraBlackout(LeafSystem):
    """Input `image` CameraFrame; output `image` CameraFrame, empty within the windows
    [(start, end), ...] [s]."""

    def __init__(self, windows):
        super().__init__()
        self._windows = np.asarray(windows, float).reshape(-1, 2)
        if not np.all(np.isfinite(self._windows)) or np.any(self._windows[:, 1]
                                                            < self._windows[:, 0]):
            raise ValueError(f"blackout windows must be finite (start, end) pairs, got {windows!r}")
        self._image = self.DeclareAbstractInputPort("image", AbstractValue.Make(CameraFrame()))
        self.DeclareAbstractOutputPort("image", lambda: AbstractValue.Make(CameraFrame()),
                                       self._calc)

    def _calc(self, context, output):
        t = context.get_time()
        dark = np.any((self._windows[:, 0] <= t) & (t < self._windows[:, 1]))
        output.set_value(CameraFrame() if dark else self._image.Eval(context))
