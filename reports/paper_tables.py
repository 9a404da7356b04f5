"""The paper's printed tables S2 and S4: moved to :mod:`twin_mapping.paper_tables` (every printed
number in one module); re-exported here for existing callers."""
from twin_mapping.paper_tables import TABLE_S2, TABLE_S4  # noqa: F401
