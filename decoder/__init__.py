"""Decoders: resistances -> forces, with a per-taxel valid mask and reason (docs/decoders.md)."""

from decoder.protocol import Decoded, Decoder
from decoder.reasons import Reason, reason_name
from decoder.registry import available_decoders, create_decoder, decoder_class, load_decoder

__all__ = ["Decoded", "Decoder", "Reason", "available_decoders", "create_decoder",
           "decoder_class", "load_decoder", "reason_name"]
