"""Words for the log: one home for counting nouns ('1 feature', '2 features')."""

def counted(n, noun: str, plural: str = None) -> str:
    """``n`` and ``noun`` in the number ``n`` takes: ``counted(1, "feature")`` is
    '1 feature', ``counted(3, "geometry")`` '3 geometries'.

    >>> counted(1, "line"), counted(0, "line"), counted(2, "geometry")
    ('1 line', '0 lines', '2 geometries')
    >>> counted(1, "connected component"), counted(5, "piece", "pieces")
    ('1 connected component', '5 pieces')
    """
    n = int(n)
    if n == 1:
        return f"1 {noun}"
    if plural is None:
        plural = noun[:-1] + "ies" if noun.endswith("y") and noun[-2:-1] not in "aeiou" \
            else noun + "s"
    return f"{n} {plural}"
