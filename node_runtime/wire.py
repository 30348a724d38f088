"""Raw samples: CDR bytes straight into and out of Cyclone, bypassing its Python serialiser."""

from __future__ import annotations

from collections.abc import Iterator

import cyclonedds._clayer as _clayer
from cyclonedds.core import InstanceState, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader


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


#: Every sample, read or not, of every instance: a reader here always wants all it holds.
ANY_STATE = SampleState.Any | ViewState.Any | InstanceState.Any


def take_raw(reader: DataReader, batch: int = 32) -> Iterator[bytes]:
    """Take every valid sample Cyclone holds for ``reader``, as CDR bytes (with header)."""
    while True:
        ret = _clayer.ddspy_take(reader._ref, ANY_STATE, batch)
        if isinstance(ret, int) or not ret:
            return
        for data, info in ret:
            if info.valid_data:
                yield data
