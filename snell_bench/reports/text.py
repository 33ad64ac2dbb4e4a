r"""The small value and text helpers every report module shares: missing values, reasons on one line,
slugs, and escaping for Markdown, LaTeX and HTML.

Conventions:
    - A value is missing when it is None or a float NaN (:func:`is_missing`); a missing reason reads
      ``"no reason recorded"`` (:data:`NO_REASON`).
    - Text from the cells (names, labels, reasons) goes on one line: every whitespace run, newlines
      included, becomes one space (:func:`one_line`); every escaping function does that first.
    - Escaping is for the format the text goes into: :func:`md_escape` and :func:`md_code` for
      Markdown, :func:`tex_escape` for LaTeX, :func:`html_escape` for the HTML that Plotly draws
      (the page's templates escape every string themselves).
"""

from __future__ import annotations

import html
import math
import re

__all__ = [
    "NO_REASON",
    "is_missing",
    "as_float",
    "one_line",
    "reason",
    "slug",
    "md_escape",
    "md_code",
    "tex_escape",
    "html_escape",
]

NO_REASON = "no reason recorded"
"""What a note or tooltip says for a value without a recorded reason."""


def is_missing(v) -> bool:
    """Whether ``v`` is a missing value: None or a float NaN (NumPy's included); anything else is not.

    Examples:
        >>> is_missing(None), is_missing(float("nan")), is_missing(0.0), is_missing("nan")
        (True, True, False, False)
    """
    return v is None or (isinstance(v, float) and math.isnan(v))


def as_float(v) -> float:
    """``float(v)``, NaN where ``v`` is None or no number.

    Examples:
        >>> as_float("2.5"), as_float(None), as_float("n/a"), as_float({})
        (2.5, nan, nan, nan)
    """
    try:
        return float("nan") if v is None else float(v)
    except (TypeError, ValueError):
        return float("nan")


def one_line(text) -> str:
    """``str(text)`` on one line: every whitespace run (newlines included) becomes one space, none
    at either end (a multi-line exception message would break a list item or a table cell).

    Examples:
        >>> one_line("CUDA out of\\n   memory ")
        'CUDA out of memory'
    """
    return " ".join(str(text).split())


def reason(why) -> str:
    """A recorded reason on one line (:func:`one_line`), :data:`NO_REASON` where it is missing.

    Examples:
        >>> reason("no VGG\\nweights"), reason(None), reason(float("nan"))
        ('no VGG weights', 'no reason recorded', 'no reason recorded')
    """
    return NO_REASON if is_missing(why) else one_line(why)


def slug(text, sep: str = "-", keep: str = "", lower: bool = True) -> str:
    """``str(text)`` as a name of ASCII letters and digits: every run of other characters (but those
    of ``keep``) becomes ``sep``, none at either end (of ``sep`` or ``keep``); lower case unless
    ``lower`` is False. It may be empty: callers give their default.

    Examples:
        >>> slug("R_main"), slug("Paper (x) a  b", "_"), slug("living_room-0/Sphere.1", keep=".-", lower=False)
        ('r-main', 'paper_x_a_b', 'living-room-0-Sphere.1')
        >>> slug("—")
        ''
    """
    text = re.sub(f"[^A-Za-z0-9{re.escape(keep)}]+", sep, str(text)).strip(sep + keep)
    return text.lower() if lower else text


# Markdown's active characters in running text and table cells: backslash, code, emphasis, links
# and images, HTML and autolinks, entities, GFM strikethrough and cell separators. An underscore
# inside a word (``living_room``) is never emphasis (CommonMark), so it is left as it is.
_MD_ACTIVE = re.compile(r"[\\`*\[\]<>&|~]|(?<![0-9A-Za-z])_|_(?![0-9A-Za-z])")


def md_escape(text) -> str:
    r"""``str(text)`` as literal Markdown text on one line (a table cell, a list item, a heading).

    Whitespace runs (newlines included) become one space; the characters Markdown would read as
    markup are backslash-escaped (CommonMark: any ASCII punctuation may be), so the text renders as
    written.

    Args:
        text: any value; its ``str``.

    Returns:
        The escaped text.

    Examples:
        >>> md_escape("a|b <i>x</i> *y* `z`")
        'a\\|b \\<i\\>x\\</i\\> \\*y\\* \\`z\\`'
        >>> md_escape("living_room\n _x_")
        'living_room \\_x\\_'
    """
    return _MD_ACTIVE.sub(lambda m: "\\" + m.group(0), one_line(text))


def md_code(text) -> str:
    """``str(text)`` as a Markdown code span on one line, fenced with more backticks than it holds.

    Examples:
        >>> md_code("runs/a`b")
        '``runs/a`b``'
    """
    text = one_line(text)
    fence = "`" * (max((len(r) for r in re.findall(r"`+", text)), default=0) + 1)
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


_LATEX_ESCAPES = {
    "\\": r"\textbackslash{}",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "|": r"\textbar{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "↑": r"$\uparrow$",
    "↓": r"$\downarrow$",
    "·": r"$\cdot$",
    "×": r"$\times$",
}


def tex_escape(s) -> str:
    r"""``str(s)`` as LaTeX text on one line: whitespace runs (newlines included: a blank line would
    end a paragraph inside a caption) become one space, LaTeX's special characters
    (``\ & % $ # _ { } ~ ^``) and ``< > |`` (other glyphs in LaTeX's default font encoding) are
    escaped, and ↑ ↓ · × become math symbols (Styler's ``escape="latex"`` leaves those four as they are).

    Examples:
        >>> tex_escape("50% of a_b & {c}\n#1 <x>")
        '50\\% of a\\_b \\& \\{c\\} \\#1 \\textless{}x\\textgreater{}'
    """
    return "".join(_LATEX_ESCAPES.get(ch, ch) for ch in one_line(s))


def html_escape(text) -> str:
    """``str(text)`` as HTML text (``&``, ``<`` and ``>`` escaped; quotes and whitespace kept): the
    strings Plotly draws as HTML (titles, trace names, labels, hover text).

    Examples:
        >>> html_escape("a<b> & 'c'")
        "a&lt;b&gt; &amp; 'c'"
    """
    return html.escape(str(text), quote=False)
