"""Radio propagation for cellular localisation: path-loss models, their inverses (RSS -> range),
GSM channel plans (ARFCN <-> frequency, the band of a channel) and the timing-advance step."""

from ._arfcn import GSM_BANDS, TA_STEP_M, GsmBand, arfcn_to_frequency, band_of_arfcn, frequency_to_arfcn
from ._inverse import (
    PATH_LOSS_MODELS,
    distance_from_path_loss,
    distance_from_rss,
    path_loss,
    path_loss_from_rss,
)
from ._pathloss import (
    cost231_hata,
    cost231_wi_los,
    cost231_wi_nlos,
    free_space_loss,
    hata_mobile_correction,
    okumura_hata,
    wi_free_space_loss,
    wi_multiscreen_loss,
    wi_orientation_loss,
    wi_rooftop_to_street_loss,
)
from ._validity import ValidityWarning

__all__ = [
    "GSM_BANDS",
    "GsmBand",
    "arfcn_to_frequency",
    "frequency_to_arfcn",
    "band_of_arfcn",
    "TA_STEP_M",
    "PATH_LOSS_MODELS",
    "path_loss",
    "path_loss_from_rss",
    "distance_from_path_loss",
    "distance_from_rss",
    "free_space_loss",
    "wi_free_space_loss",
    "wi_orientation_loss",
    "wi_rooftop_to_street_loss",
    "wi_multiscreen_loss",
    "cost231_wi_los",
    "cost231_wi_nlos",
    "cost231_hata",
    "okumura_hata",
    "hata_mobile_correction",
    "ValidityWarning",
]
