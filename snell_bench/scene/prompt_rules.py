"""The rules that derive every prompt of the method from one prompt with a marked object phrase.

The user writes one prompt and marks the phrase that places the glass object with double square
brackets (config key ``scene.text``)::

    A cozy living room with a polished wooden coffee table close to the camera,
    [[with a big glass sphere on top,]] surrounded by a beige sofa, ...

:func:`decompose` turns it into :class:`Prompts`:

    - ``full`` (p): the prompt with the brackets removed, the phrase kept.
    - ``minus`` (p⁻): the object-free prompt, the phrase replaced by wording that the surface is
      clean and empty.
    - ``object_phrase`` (p_obj): the phrase without its placement words, ``"a big glass sphere"``.
    - ``noun`` and ``materials``: ``"sphere"`` and ``("glass",)``; :meth:`Prompts.with_object` swaps
      the noun (``{object}`` may stand for it, as in ``[[with a big glass {object} on top,]]``).
    - ``surface``: what the object stands on, for a text-prompted segmenter.
    - ``scene``: the scene's own noun phrase, ``"a cozy living room"``.
    - ``pano`` (p³⁶⁰): the panorama prompt.

Rules (the phrase is read after dropping its trailing punctuation, which is kept in p⁻):

    - Placement words: the phrase is ``[with] <object phrase> [<verb>] <placement>``, where the
      placement is the first ``on top``, ``on top of <NP>``, ``on <NP>``, ``upon <NP>`` or
      ``atop <NP>`` in it, optionally preceded by one of :data:`PLACEMENT_VERBS` ("placed",
      "standing", ...). The object phrase is what precedes it, the leading ``with`` dropped; its
      last word is the noun, and its words in :data:`MATERIAL_WORDS` are the materials. Other
      placement words ("next to", "in front of", "beside", "under", "in", ...) end the object
      phrase too, but p⁻ and the surface must then be given explicitly.
    - p⁻, the placement rewritten (a leading ``with`` kept):
        ``on top`` -> ``its clean, empty top`` (``with its clean, empty top,``);
        ``on top of X`` -> ``the clean, empty top of X``;
        ``on the G`` with G a ground (:data:`GROUND_NOUNS`) -> ``the clean, empty G in front``;
        ``on the X`` -> ``the clean, empty X top``;
        ``on a X`` -> ``a clean, empty X``.
    - Surface: for ``on top``, the nearest support noun phrase before the marked phrase: the
      nearest preceding word in :data:`SUPPORT_NOUNS` (plurals too) that heads its noun phrase
      (followed by punctuation, the marked phrase, a function word such as "in", "near", "close",
      or a word ending in "-ed" / "-ing"), extended to the left up to and including a determiner,
      or up to a preposition, conjunction or punctuation mark (at most 8 words). For ``on the X``
      / ``on top of the X`` it is the nearest preceding noun phrase headed by X's last word (the
      antecedent: "a stone table ... [[... on the table,]]" gives "stone table"), else X itself;
      ``on a X`` gives X. ``surface`` carries no leading determiner ("polished wooden coffee
      table", "ground"); the panorama prompt uses the phrase as written ("a polished wooden coffee
      table").
    - Scene: the leading noun phrase of the prompt without the marked phrase: leading stop words
      and punctuation skipped, the words up to the first punctuation mark or the first of
      :data:`SCENE_STOP_WORDS` ("with", "lit", "in", ...); a capitalised leading determiner is
      lower-cased ("A cozy living room with ..." -> "a cozy living room").
    - p³⁶⁰: ``A high resolution equirectangular 360 degree panorama captured on top of <surface
      phrase> in <scene>.``, and for a ground ``... captured from the <ground> of <scene>.``.

Limits: the rules are lexical, not a parser. A support noun missing from :data:`SUPPORT_NOUNS`
is not found ("on top" then needs an explicit surface); a support noun used as a modifier is
skipped ("a table lamp"), except before a noun ending in "-ed" / "-ing" ("a table setting" gives
"table"); only the text before the marked phrase is searched; pronouns ("on it") are not resolved; the
scene is the first noun phrase, whatever it is. Any derived prompt can be given explicitly:
``decompose(text, minus=..., pano=..., surface=...)``.

Optionally, :func:`~snell_bench.scene.prompt_llm.decompose_with_llm` asks a local text-generation
model to mark an unmarked prompt and then calls :func:`decompose`. :mod:`snell_bench.scene.prompts`
exports both.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, replace

__all__ = [
    "GROUND_NOUNS",
    "MATERIAL_WORDS",
    "PANO_PREFIX",
    "SUPPORT_NOUNS",
    "Prompts",
    "decompose",
]

#: Config keys named in error messages.
TEXT_KEY = "scene.text"
SURFACE_KEY = "scene.surface"
MINUS_KEY = "scene.prompt_minus"
PANO_KEY = "scene.pano_prompt"
LLM_KEY = "scene.prompt_llm"

OPEN, CLOSE = "[[", "]]"
#: The form :func:`decompose` expects, shown in its error messages.
EXAMPLE = (
    "A cozy living room with a wooden coffee table close to the camera, "
    "[[with a big glass sphere on top,]] surrounded by a beige sofa."
)
#: The opening words of every derived panorama prompt.
PANO_PREFIX = "A high resolution equirectangular 360 degree panorama captured"

#: Nouns of things an object can stand on ("on top" looks for the nearest one before the phrase).
SUPPORT_NOUNS = frozenset(
    """table worktable desk island counter countertop worktop bench workbench stool shelf bookshelf
    sideboard dresser cabinet chest nightstand stand pedestal plinth podium box crate trunk tray board
    platform ledge sill windowsill mantel mantelpiece piano altar bar boulder stump log block ottoman
    bed floor ground""".split()
)
#: Surfaces one stands on rather than on top of: p⁻ says "the clean, empty <G> in front" and p³⁶⁰
#: is captured "from the <G> of" the scene.
GROUND_NOUNS = frozenset(
    """ground floor sand grass lawn snow beach soil dirt earth road street pavement sidewalk path field
    meadow moss gravel""".split()
)
#: Words of an object phrase that name its material.
MATERIAL_WORDS = frozenset(
    """glass crystal ice water acrylic quartz sapphire diamond zirconia cubic crown flint plexiglass
    perspex resin plastic amber""".split()
)
#: Verbs that may stand between the object phrase and its placement ("a glass sphere placed on ...").
PLACEMENT_VERBS = frozenset(
    """placed standing sitting resting lying set positioned perched sits stands rests lies""".split()
)
#: Words that end the scene's leading noun phrase.
SCENE_STOP_WORDS = frozenset(
    """with lit viewed seen in on at near under by of from for where that which and filled overlooking
    featuring showing during beside behind facing""".split()
)

_DETERMINERS = frozenset(
    """a an the its their his her our my your this that these those one two three four five some
    several""".split()
)
#: Words that end a noun phrase when scanning left from its head.
_NP_BOUNDARY = frozenset(
    """with in on at near by of from and or to under over behind beside besides next against among
    between across along around below above beneath underneath inside outside into onto for where
    which while as""".split()
)
#: Words after a support noun that show it heads its noun phrase.
_AFTER_HEAD = _NP_BOUNDARY | frozenset(
    """close closer nearer directly right just facing set placed is are sits stands that""".split()
)
_TOKEN = re.compile(r"\{object\}|\w[\w'’-]*|[^\w\s]")
_PLACEMENT = re.compile(
    r"(?:^|\s+)(?:(?P<verb>" + "|".join(sorted(PLACEMENT_VERBS)) + r")\s+)?"
    r"(?:(?P<top>on\s+top)(?:\s+of\s+(?P<top_np>\S.*))?|(?:on|upon|atop)\s+(?P<np>\S.*))$",
    re.IGNORECASE,
)
#: Other placement words: they end the object phrase, but p⁻ and the surface must then be given.
_OTHER_PLACEMENT = re.compile(
    r"\s+(?:(?:" + "|".join(sorted(PLACEMENT_VERBS)) + r")\s+)?"
    r"(?:next\s+to|in\s+front\s+of|beside|near|by|behind|under|beneath|below|inside|in|among|against|between|at|over"
    r"|above)\s+\S",
    re.IGNORECASE,
)
_SPACE = re.compile(r"\s+")


def _error(text: str, problem: str) -> ValueError:
    return ValueError(
        f"{problem} in the prompt {text!r} (config key {TEXT_KEY}). Mark the phrase that places the glass "
        f"object with double square brackets, exactly once, e.g. {EXAMPLE!r}"
    )


def _article(word: str) -> str:
    return "an" if word[:1].lower() in "aeiou" else "a"


def _lower_determiner(phrase: str) -> str:
    first, _, rest = phrase.partition(" ")
    return f"{first.lower()} {rest}".strip() if first.lower() in _DETERMINERS else phrase


def _bare(phrase: str) -> str:
    """``phrase`` without a leading determiner."""
    first, _, rest = phrase.partition(" ")
    return rest if first.lower() in _DETERMINERS and rest else phrase


def _singular(word: str) -> str:
    w = word.lower()
    if w == "shelves":
        return "shelf"
    if w.endswith("es") and w[:-2] in SUPPORT_NOUNS | GROUND_NOUNS:
        return w[:-2]
    if w.endswith("s") and w[:-1] in SUPPORT_NOUNS | GROUND_NOUNS:
        return w[:-1]
    return w


def _is_word(token: str) -> bool:
    return token == "{object}" or token[:1].isalnum() or token[:1] == "_"


def _heads_phrase(tokens: list[str], i: int) -> bool:
    """Whether ``tokens[i]`` ends its noun phrase (see the module's surface rule)."""
    if i + 1 == len(tokens):
        return True
    nxt = tokens[i + 1].lower()
    return not _is_word(nxt) or nxt in _AFTER_HEAD or nxt.endswith(("ed", "ing"))


def _noun_phrase(tokens: list[str], head: int) -> str:
    """The noun phrase ending at ``tokens[head]``, extended left (see the module's surface rule)."""
    start = head
    while start > 0 and head - start < 7:
        tok = tokens[start - 1]
        if not _is_word(tok) or tok.lower() in _NP_BOUNDARY:
            break
        start -= 1
        if tok.lower() in _DETERMINERS:
            break
    return _lower_determiner(" ".join(tokens[start : head + 1]))


def _antecedent(before: str, match: Callable[[str], bool]) -> str | None:
    """The nearest noun phrase in ``before`` whose head satisfies ``match``."""
    tokens = _TOKEN.findall(before)
    for i in range(len(tokens) - 1, -1, -1):
        if _is_word(tokens[i]) and match(_singular(tokens[i])) and _heads_phrase(tokens, i):
            return _noun_phrase(tokens, i)
    return None


def _scene_phrase(text: str) -> str:
    """The prompt's leading noun phrase (see the module's scene rule)."""
    tokens = _TOKEN.findall(text)
    while tokens and (not _is_word(tokens[0]) or tokens[0].lower() in SCENE_STOP_WORDS):
        tokens.pop(0)  # a prompt that opens with the marked phrase: "[[...]] in a restaurant"
    words = []
    for tok in tokens:
        if not _is_word(tok) or tok.lower() in SCENE_STOP_WORDS:
            break
        words.append(tok)
    return _lower_determiner(" ".join(words)) if words else "the scene"


def _split_marked(text: str) -> tuple[str, str, str]:
    """``(before, phrase, after)`` of a prompt with one ``[[phrase]]``; ``ValueError`` otherwise."""
    if not isinstance(text, str):
        raise TypeError(f"the prompt ({TEXT_KEY}) must be a string, got {type(text).__name__} {text!r}")
    n_open, n_close = text.count(OPEN), text.count(CLOSE)
    if n_open == 0 and n_close == 0:
        raise _error(text, "no object phrase is marked with [[...]]")
    if n_open != n_close:
        raise _error(text, f"unbalanced brackets ({n_open} '[[' and {n_close} ']]')")
    if n_open > 1:
        raise _error(text, f"{n_open} phrases are marked; mark only the one that places the object")
    i, j = text.index(OPEN), text.index(CLOSE)
    if j < i:
        raise _error(text, "unbalanced brackets (']]' before '[[')")
    phrase = text[i + len(OPEN) : j]
    if not phrase.strip(" \t\n,.;:"):
        raise _error(text, "the marked object phrase is empty")
    return text[:i], phrase, text[j + len(CLOSE) :]


@dataclass(frozen=True)
class Prompts:
    """The prompts of one scene, derived from its marked prompt by :func:`decompose`.

    Attributes:
        full: p, the full prompt (brackets removed, the object phrase kept).
        minus: p⁻, the object-free prompt.
        pano: p³⁶⁰, the panorama prompt.
        object_phrase: p_obj, the object phrase without placement words ("a big glass sphere").
        noun: the object's noun ("sphere"; ``"{object}"`` when the prompt uses the placeholder).
        surface: what the object stands on, without a leading determiner ("polished wooden coffee
            table", "ground", "stone table").
        materials: the material words of the object phrase (``("glass",)``).
        scene: the scene's leading noun phrase ("a cozy living room").
        text: the marked prompt these prompts were derived from.
    """

    full: str
    minus: str
    pano: str
    object_phrase: str
    noun: str
    surface: str
    materials: tuple[str, ...] = ()
    scene: str = ""
    text: str = ""

    def with_object(self, noun: str) -> Prompts:
        """The same prompts for another object noun (p⁻, p³⁶⁰ and the surface are kept).

        Args:
            noun: the new noun, e.g. ``"fox"`` (several words allowed: ``"rubber duck"``). An
                article directly before the noun becomes "a" / "an" to match it.

        Returns:
            The prompts with ``full``, ``object_phrase``, ``noun`` and ``text`` for ``noun``.

        Raises:
            ValueError: for an empty noun or one with brackets.
        """
        noun = _SPACE.sub(" ", str(noun)).strip()
        if not noun or OPEN[0] in noun or CLOSE[0] in noun:
            raise ValueError(f"the object noun must be a non-empty word without brackets, got {noun!r}")
        words = self.object_phrase.split(" ")
        words[-1] = noun
        if len(words) > 1 and words[-2].lower() in ("a", "an"):
            art = _article(noun)
            words[-2] = art.capitalize() if words[-2][0].isupper() else art
        new_phrase = " ".join(words)
        before, phrase, after = _split_marked(self.text)
        at = phrase.index(self.object_phrase)
        phrase = phrase[:at] + new_phrase + phrase[at + len(self.object_phrase) :]
        text = before + OPEN + phrase + CLOSE + after
        return replace(self, full=before + phrase + after, object_phrase=new_phrase, noun=noun, text=text)


def decompose(text: str, *, pano: str | None = None, surface: str | None = None, minus: str | None = None) -> Prompts:
    """Every prompt of the method from one prompt whose object phrase is marked ``[[...]]``.

    The rules are those of the module docstring; an explicit argument replaces the derived value
    (a surface given here also enters the derived p³⁶⁰, with "a" / "an" unless it starts with a
    determiner).

    Args:
        text: the marked prompt (config key ``scene.text``), e.g. ``"..., [[with a big glass
            sphere on top,]] surrounded by ..."``.
        pano: p³⁶⁰ to use instead of the derived one.
        surface: the supporting surface to use instead of the derived one.
        minus: p⁻ to use instead of the derived one.

    Returns:
        The :class:`Prompts`.

    Raises:
        ValueError: when no phrase is marked, more than one is, the brackets are unbalanced or the
            phrase is empty (the message quotes the prompt, names ``scene.text`` and shows the
            expected form); when the phrase has no placement words the rules know and ``minus``
            or ``surface`` is not given; when "on top" finds no support before the phrase and
            ``surface`` is not given.

    Examples:
        >>> p = decompose(
        ...     "A cozy living room with a polished wooden coffee table close to the camera, "
        ...     "[[with a big glass sphere on top,]] surrounded by a beige sofa."
        ... )
        >>> p.full
        'A cozy living room with a polished wooden coffee table close to the camera, with a big glass sphere on top, surrounded by a beige sofa.'
        >>> p.minus
        'A cozy living room with a polished wooden coffee table close to the camera, with its clean, empty top, surrounded by a beige sofa.'
        >>> p.object_phrase, p.noun, p.materials, p.surface
        ('a big glass sphere', 'sphere', ('glass',), 'polished wooden coffee table')
        >>> p.pano
        'A high resolution equirectangular 360 degree panorama captured on top of a polished wooden coffee table in a cozy living room.'
        >>> p.with_object("fox").full
        'A cozy living room with a polished wooden coffee table close to the camera, with a big glass fox on top, surrounded by a beige sofa.'
    """
    before, phrase, after = _split_marked(text)
    lead, with_word, core, tail = _phrase_parts(phrase)
    m, obj = _placement(core, text)
    words = obj.split()
    derived_minus, surface_np = _minus_and_surface(m, before, phrase, text, surface)
    if minus is None:
        minus = _minus_prompt(derived_minus, before, lead, with_word, tail, after, phrase, text)
    if surface is not None:
        surface_np = _SPACE.sub(" ", surface).strip()
        if not surface_np:
            raise ValueError(f"the surface ({SURFACE_KEY}) must not be empty for the prompt {text!r}")
        if surface_np.split(" ")[0].lower() not in _DETERMINERS:
            surface_np = f"{_article(surface_np)} {surface_np}"
    if surface_np is None:
        raise ValueError(
            f"the object phrase {phrase.strip()!r} names no surface in the prompt {text!r} (config key "
            f"{TEXT_KEY}); name it explicitly (surface=..., config key {SURFACE_KEY})"
        )
    bare_surface = _bare(surface_np)
    scene = _scene_phrase(before + after)
    if pano is None:
        if _singular(bare_surface.split()[-1]) in GROUND_NOUNS:
            pano = f"{PANO_PREFIX} from the {bare_surface} of {scene}."
        else:
            pano = f"{PANO_PREFIX} on top of {surface_np} in {scene}."
    materials = tuple(w for w in words[:-1] if w.lower() in MATERIAL_WORDS)
    return Prompts(before + phrase + after, minus, pano, obj, words[-1], bare_surface, materials, scene, text)


def _phrase_parts(phrase: str) -> tuple[str, str, str, str]:
    """``(lead, with_word, core, tail)``: the phrase's leading space, leading "with ", rest, trailing punctuation."""
    core = phrase.rstrip(" \t\n,.;:")
    tail = phrase[len(core) :]
    lead = core[: len(core) - len(core.lstrip())]
    core = core.strip()
    with_word = ""
    m_with = re.match(r"with\s+", core, re.IGNORECASE)
    if m_with:
        with_word, core = core[: m_with.end()], core[m_with.end() :]
    return lead, with_word, core, tail


def _placement(core: str, text: str) -> tuple[re.Match | None, str]:
    """``(match of the known placement words or None, object phrase)``: the core phrase split at its placement."""
    m = _PLACEMENT.search(core)
    other = None if m else _OTHER_PLACEMENT.search(core)
    obj = (core[: m.start()] if m else core[: other.start()] if other else core).strip()
    if not obj:
        raise _error(text, "the marked phrase names no object before its placement words")
    return m, obj


def _minus_and_surface(m: re.Match | None, before: str, phrase: str, text: str, surface: str | None):
    """``(p⁻ wording of the placement, surface with its determiner)``; ``None`` where the rules give none."""
    if not m:
        return None, None
    if m.group("top") and not m.group("top_np"):
        surface_np = _antecedent(before, lambda w: w in SUPPORT_NOUNS)
        if surface_np is None and surface is None:
            raise ValueError(
                f"the object phrase {phrase.strip()!r} says 'on top' but no supporting surface (one of "
                f"{', '.join(sorted(SUPPORT_NOUNS))}) precedes it in the prompt {text!r} (config key {TEXT_KEY}); "
                f"name the surface explicitly (surface=..., config key {SURFACE_KEY})"
            )
        return "its clean, empty top", surface_np
    np_text = (m.group("top_np") or m.group("np")).strip()
    det, _, rest = np_text.partition(" ")
    det_l = det.lower()
    head = _singular(np_text.split()[-1])
    is_ground = head in GROUND_NOUNS
    if m.group("top_np"):
        derived_minus = f"the clean, empty top of {np_text}"
    elif det_l in _DETERMINERS and rest:
        if is_ground:
            derived_minus = f"the clean, empty {rest} in front"
        elif det_l in ("a", "an"):
            derived_minus = f"a clean, empty {rest}"
        else:
            derived_minus = f"the clean, empty {rest} top"
    else:
        derived_minus = f"the clean, empty {np_text} in front" if is_ground else f"the clean, empty {np_text} top"
    surface_np = np_text
    if det_l not in ("a", "an"):
        surface_np = _antecedent(before, lambda w: w == head) or _lower_determiner(np_text)
    return derived_minus, surface_np


def _minus_prompt(derived_minus, before, lead, with_word, tail, after, phrase, text) -> str:
    """p⁻: the prompt, the phrase replaced by ``derived_minus`` ("with " kept, capitalised at a sentence start)."""
    if derived_minus is None:
        raise ValueError(
            f"the object phrase {phrase.strip()!r} has no placement words the rules know ('on top', "
            f"'on top of <surface>', 'on <surface>') in the prompt {text!r} (config key {TEXT_KEY}); rephrase "
            f"it, or give the object-free prompt explicitly (minus=..., config key {MINUS_KEY})"
        )
    if with_word:
        derived_minus = with_word + derived_minus
    at_start = not before.strip() or before.rstrip().endswith((".", "!", "?"))
    if at_start:
        derived_minus = derived_minus[0].upper() + derived_minus[1:]
    return before + lead + derived_minus + tail + after
