"""Tritech SeaNet (MSIS): everything about the protocol in one package.

* :mod:`.codec` (re-exported here): packets, the framer and the :data:`FORMAT` of a serial
  capture;
* :mod:`.v4log`: the Seanet ``.V4LOG`` recording (format ``v4log``);
* :mod:`.host`: the host's polling state machine (:class:`~.host.SeaNetHost`), pure: the gateway
  hands it ``write`` and ``now``.
"""

from auvgw.drivers.seanet.codec import *  # noqa: F403
from auvgw.drivers.seanet.codec import __all__ as __all__
