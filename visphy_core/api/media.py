"""Video and image I/O for plugins: decoding and encoding clips with the run's codec settings,
reading frames an untrusted program wrote (bounded, no links), PNG bytes, resampling a clip
to the reference's time grid (`visphy_core.infra.video`, `visphy_core.infra.png`)."""

from __future__ import annotations

from visphy_core.infra.png import DeadlineExceeded, FrameRejected, decode_png, png_bytes
from visphy_core.infra.video import (
    ClipInfo,
    PUBLISHED_CRF,
    VideoBudget,
    decode_video,
    decode_video_timed,
    encode_video,
    read_untrusted_frames,
    read_untrusted_raw_frames,
    resample_by_time,
    resize_with_padding,
)

__all__ = [
    "ClipInfo", "DeadlineExceeded", "decode_png", "decode_video", "decode_video_timed",
    "encode_video", "FrameRejected", "png_bytes", "PUBLISHED_CRF", "read_untrusted_frames",
    "read_untrusted_raw_frames", "resample_by_time", "resize_with_padding", "VideoBudget",
]
