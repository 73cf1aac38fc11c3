"""Model components: each a small object with a prior, a forward function and
a ``physical`` method turning its scaled draws into reported quantities.

Roles in the measurement equation (docs/architecture.md, section 2)::

    DN = offset(gain, t) + S(x * (1 + e_level) * f_gain f_exposure f_tdi) (clipped at full scale) + noise

Adding a component does not touch the others; the assembly in
:mod:`bayescal.assemble` wires them together.
"""

from bayescal.model.components.dark import Dark
from bayescal.model.components.noise import Noise
from bayescal.model.components.response import Response
from bayescal.model.components.saturation import Saturation
from bayescal.model.components.settings import SettingFactors
from bayescal.model.components.sphere import Sphere

__all__ = ["Dark", "Noise", "Response", "Saturation", "SettingFactors", "Sphere"]
