"""Which DJI camera wrote an MP4, from the file's own metadata (read by app.io.mp4box, no decoding).

DJI's subtitles (.SRT) never name the aircraft, so the video is the only witness:
- moov/udta '\\xa9mdl': the camera's code, a bare string without the usual text header (ExifTool
  calls it a non-standard DJI tag): 'FC3170' for a Mavic Air 2, as in the EXIF Model of the
  aircraft's photos. The codes below are the ones public camera databases agree on.
- the encoder string ('\\xa9too' in udta or ilst): newer models write the product there,
  'DJIMavic3', 'DJI Air3', 'DJI OsmoPocket3'; anything not starting with 'DJI' (a re-encode by
  other software) is ignored.
- stream handler names 'DJI.AVC', 'DJI.Meta' (read by PyAV) say only that DJI wrote the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from app.io.mp4box import udta_text, user_data

# Camera code ('\xa9mdl', also the Model of the aircraft's photos) -> the aircraft's name.
DJI_CAMERA_CODES = {
    "FC220": "Mavic Pro",
    "FC3170": "Mavic Air 2",
    "FC3411": "Air 2S",
    "FC7203": "Mavic Mini",
    "FC7303": "Mini 2",
    "FC3582": "Mini 3 Pro",
    "FC3682": "Mini 3",
    "FC8482": "Mini 4 Pro",
    "FC2200": "Mavic 2 Zoom",
    "L1D-20C": "Mavic 2 Pro",
    "L2D-20C": "Mavic 3",
    "FC300S": "Phantom 3 Advanced",
    "FC300X": "Phantom 3 Professional",
    "FC300C": "Phantom 3 Standard",
    "FC330": "Phantom 4",
    "FC6310": "Phantom 4 Pro",
    "FC6310S": "Phantom 4 Pro V2",
    "FC6310R": "Phantom 4 RTK",
    "FC1102": "Spark",
    "FC6510": "Zenmuse X4S",
    "FC6520": "Zenmuse X5S",
    "FC6540": "Zenmuse X7",
}


@dataclass(frozen=True)
class DjiCamera:
    """What a DJI MP4 says of its camera. model: the aircraft or camera's name ('' when unknown);
    code: the camera code ('FC3170', '' when absent); encoder: the encoder string as written;
    found_in: where the model came from, for messages."""

    model: str
    code: str
    encoder: str
    found_in: str

    @property
    def described(self) -> str:
        """The camera for messages: 'DJI Mavic Air 2 (camera code FC3170 in the MP4)'."""
        return (
            f"DJI {self.model} ({self.found_in})"
            if self.model
            else f"a DJI camera ({self.found_in})"
        )


def read_dji_camera(path: str | Path) -> DjiCamera | None:
    """The DJI camera that wrote the MP4 at path, or None when its metadata names no DJI camera.
    A camera code that is not in DJI_CAMERA_CODES is kept (model '') so that it can be reported."""
    meta = user_data(path)
    code = udta_text(meta.get("\xa9mdl", b"")).upper()
    encoder = udta_text(meta.get("\xa9too", b""))
    by_encoder = _encoder_model(encoder)
    if code in DJI_CAMERA_CODES:
        return DjiCamera(DJI_CAMERA_CODES[code], code, encoder, f"camera code {code} in the MP4")
    if by_encoder:
        return DjiCamera(by_encoder, code, encoder, f"encoder '{encoder}' in the MP4")
    if code:
        return DjiCamera("", code, encoder, f"camera code {code} in the MP4")
    return None


def _encoder_model(encoder: str) -> str:
    """'DJIMavic3' -> 'Mavic3', 'DJI Air3' -> 'Air3'; '' for a string DJI did not write."""
    text = encoder.strip()
    if not text.upper().startswith("DJI") or text.upper().startswith("DJI."):
        return ""
    return text[3:].strip(" _-")
