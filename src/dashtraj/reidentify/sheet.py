"""A contact sheet of a ReID query: the query's crop(s) above the best crop of each of
the top-ranked tracks, each under its label (Pillow; no file I/O here).

Layout (pixels): cells of ``cell`` × ``cell`` with the crop letterboxed (aspect ratio
kept, grey borders), a caption band of ``LINE_PX`` per label line below each cell, a
``GAP`` between cells; row 0 holds the query crops (blue frame), the next rows the
results in rank order, ``columns`` per row (green frame where the result shows the
query's vehicle, red where it shows another, grey when the truth is unknown).
"""

from __future__ import annotations

from collections.abc import Sequence

GAP = 6
LINE_PX = 13
_BG = (255, 255, 255)
_PAD = (200, 200, 200)
_QUERY = (40, 90, 220)
_TRUE = (30, 160, 60)
_FALSE = (210, 40, 40)
_UNKNOWN = (140, 140, 140)


def _letterbox(im, cell: int):
    from PIL import Image

    im = im.convert("RGB")
    s = min(cell / im.width, cell / im.height)
    w, h = max(1, round(im.width * s)), max(1, round(im.height * s))
    out = Image.new("RGB", (cell, cell), _PAD)
    out.paste(im.resize((w, h), Image.Resampling.BILINEAR), ((cell - w) // 2, (cell - h) // 2))
    return out


def contact_sheet(queries: Sequence, query_labels: Sequence[Sequence[str]],
                  results: Sequence, result_labels: Sequence[Sequence[str]],
                  result_match: Sequence[bool | None] | None = None, cell: int = 128,
                  columns: int = 5):
    """The sheet as a Pillow RGB image (module docstring).

    Args:
        queries: query crops (Pillow images), shown in row 0 (at most ``columns``).
        query_labels: lines under each query crop.
        results: best crop of each ranked track, in rank order.
        result_labels: lines under each result.
        result_match: per result, True (the query's vehicle), False (another) or None
            (unknown): the frame's colour.
        cell: crop cell size, pixels. columns: cells per row.
    """
    from PIL import Image, ImageDraw

    if len(queries) != len(query_labels) or len(results) != len(result_labels):
        raise ValueError("one label list per crop")
    match = list(result_match) if result_match is not None else [None] * len(results)
    queries = list(queries)[:columns]
    n_lines = max([len(x) for x in list(query_labels) + list(result_labels)] + [1])
    cap = n_lines * LINE_PX + 4
    rows = 1 + (len(results) + columns - 1) // columns
    ncol = max(1, min(columns, max(len(queries), len(results))))
    width = GAP + ncol * (cell + GAP)
    height = GAP + rows * (cell + cap + GAP)
    sheet = Image.new("RGB", (width, height), _BG)
    draw = ImageDraw.Draw(sheet)

    def put(im, labels, col, row, colour):
        x = GAP + col * (cell + GAP)
        y = GAP + row * (cell + cap + GAP)
        sheet.paste(_letterbox(im, cell), (x, y))
        draw.rectangle([x - 2, y - 2, x + cell + 1, y + cell + 1], outline=colour, width=2)
        for i, line in enumerate(labels):
            draw.text((x, y + cell + 3 + i * LINE_PX), str(line), fill=(0, 0, 0))

    for i, (im, lab) in enumerate(zip(queries, query_labels, strict=False)):
        put(im, lab, i, 0, _QUERY)
    for i, (im, lab) in enumerate(zip(results, result_labels, strict=True)):
        colour = _UNKNOWN if match[i] is None else (_TRUE if match[i] else _FALSE)
        put(im, lab, i % columns, 1 + i // columns, colour)
    return sheet
