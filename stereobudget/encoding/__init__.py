"""The camera side: select the samples of the right image, code them within a byte budget, write the ``.sbs`` file."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_select': ['encode_image'],
    '_encoder': ['EncodeReport', 'encode_file', 'encode_frame'],
    '_budget': ['check_budget', 'BudgetSearch', 'fit_budget', 'BUDGET_QUALITIES', 'BUDGET_DROPPED_BITS', 'MAX_BUDGET_STRIDE'],
})
