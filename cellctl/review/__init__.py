"""Operator review: the hash-chained review ledger, the bank of reviewed views, re-enrollment from it."""

from cellctl.review.bank import BANK_FORMAT, ReviewBank, bank_dir, open_bank
from cellctl.review.config import ReviewConfig
from cellctl.review.ledger import LEDGER_FORMAT, LEDGER_NAME, Ledger, LedgerProblem, check_ledger, entry_hash

__all__ = [
    "BANK_FORMAT",
    "LEDGER_FORMAT",
    "LEDGER_NAME",
    "Ledger",
    "LedgerProblem",
    "ReviewBank",
    "ReviewConfig",
    "bank_dir",
    "check_ledger",
    "entry_hash",
    "open_bank",
]
