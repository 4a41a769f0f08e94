"""The study report and its verdicts: results loaded once, one module per section family, the thesis's
findings decided."""
