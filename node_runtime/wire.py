"""Raw sample writing: CDR bytes straight into Cyclone, bypassing its Python serialiser."""

from __future__ import annotations

import cyclonedds._clayer as _clayer
from cyclonedds.pub import DataWriter


def write_raw(writer: DataWriter, payload: bytes) -> None:
    """Write CDR bytes (with header) as one sample; Cyclone wants a 4-byte multiple.

    Cyclone checks the bytes against the topic type and refuses what does not match, which is
    how a codec/type mismatch surfaces at once instead of on a remote reader.
    """
    pad = (-len(payload)) % 4
    ret = _clayer.ddspy_write(writer._ref, payload + b"\x00" * pad if pad else payload)
    if ret < 0:
        raise RuntimeError(f"DDS refused a {len(payload)}-byte sample on {writer.topic.name} "
                           f"(code {ret}): the bytes do not match the topic type")
