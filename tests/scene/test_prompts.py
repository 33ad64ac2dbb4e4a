"""One marked prompt -> p, p⁻, p_obj, noun, surface and p³⁶⁰: the ten paper scenes against the
paper's p and p³⁶⁰ (and snell_bench's wording of its p⁻ rule), the rules beyond them, the errors, and
the LLM path's parsing."""

import doctest
from pathlib import Path

import pytest
from omegaconf import OmegaConf

import snell_bench.scene.prompt_rules as rules_module
import snell_bench.scene.prompts as prompts_module
from snell_bench.models.errors import WeightsNotFoundError
from snell_bench.scene.prompts import PANO_PREFIX, Prompts, decompose, decompose_with_llm

SCENES_DIR = Path(prompts_module.__file__).resolve().parents[1] / "conf" / "scene"

#: The paper's prompts in the marked form (the configs' ``prompt`` with ``{object}`` -> sphere).
MARKED = {
    "artroom": "An art classroom with a rectangular wooden worktable near the camera, [[with a big glass sphere on top,]] surrounded by easels, color splattered stools, sketches, jars of brushes, and warm daylight through wide windows.",
    "cafe": "A minimalist café interior with a square wooden table in the foreground, [[with a big glass sphere on top,]] surrounded by metal framed chairs, plants, hanging lights, a pastry counter, and sunlight on the tiled floor.",
    "cave": "A rocky cave lit by a bright campfire, warm flickering light casting shadows, [[a big glass sphere on the ground,]] with scattered camping gear, tents, sleeping bags, backpacks, lanterns, and cooking pots, with smoke and embers in the air.",
    "desert": "A high-noon desert scene with blinding sunlight and hard shadows, heat haze over sand and rocks, [[a big glass sphere on the ground,]] and camping gear in the foreground, tent, backpacks, and a small stove.",
    "dining_room": "A bright dining room with a wooden dining table in the center, [[with a big glass sphere on top,]] surrounded by upholstered chairs, a pendant lamp, fruit bowls, paintings, and daylight through tall windows.",
    "karaoke": "A karaoke room with colorful lights, TV on the wall displaying music videos, a coffee table [[with a big glass sphere on top,]] in front of the TV, and a sofa around the coffee table.",
    "kitchen": "A modern kitchen with a large marble island in the center, [[with a big glass sphere on top,]] surrounded by wooden cabinetry, bar stools, hanging lights, utensils, and reflections from stainless steel appliances under morning light.",
    "landscape": "A beautiful landscape with a river and mountains, viewed from a camera directly in front of a stone table and chairs in the foreground, filling the lower frame, [[a big glass sphere on the table,]] on the left of colorful food.",
    "living_room": "A cozy living room with a polished wooden coffee table close to the camera, [[with a big glass sphere on top,]] surrounded by a beige sofa, a patterned rug, plants, bookshelves, framed wall art, and sunlight through sheer curtains.",
    "office": "A minimalist home office with a smooth wooden desk closer to the camera, [[with a big glass sphere on top,]] surrounded by a black office chair, bookshelves with plants, framed posters, a side table with a monitor.",
}

#: The derived surface of each scene.
SURFACE = {
    "artroom": "rectangular wooden worktable",
    "cafe": "square wooden table",
    "cave": "ground",
    "desert": "ground",
    "dining_room": "wooden dining table",
    "karaoke": "coffee table",
    "kitchen": "large marble island",
    "landscape": "stone table",
    "living_room": "polished wooden coffee table",
    "office": "smooth wooden desk",
}

#: Scenes whose printed p³⁶⁰ (the paper's) the rule reproduces exactly.
PANO_EXACT = ("cafe", "dining_room", "living_room", "office")
#: The derived p³⁶⁰ of the others (the paper's wording of theirs is not derivable by a rule).
PANO_DERIVED = {
    "artroom": "on top of a rectangular wooden worktable in an art classroom.",  # config: "a wooden worktable in an artroom"
    "cave": "from the ground of a rocky cave.",  # config adds ", camping gear scattering around"
    "desert": "from the ground of a high-noon desert scene.",  # config: "a desert scene, with camping gear around"
    "karaoke": "on top of a coffee table in a karaoke room.",  # config: "from on top of ... a colorful karaoke room"
    "kitchen": "on top of a large marble island in a modern kitchen.",  # config: "a marble island"
    "landscape": "on top of a stone table in a beautiful landscape.",  # config: "from on top of ... of a beautiful ..."
}


#: The paper's p (with ``{object}``) and p³⁶⁰, and snell_bench's wording of the paper's p⁻ rule, kept
#: apart from the scene configs, which derive theirs from the marked prompt.
PAPER = Path(__file__).resolve().parent / "data" / "paper_prompts.yaml"


def scene_config(name):
    return OmegaConf.load(PAPER)[name]


def test_the_ten_scenes_are_the_configs():
    assert set(MARKED) == set(SURFACE) == set(PANO_EXACT) | set(PANO_DERIVED)
    for name in MARKED:
        assert (SCENES_DIR / f"{name}.yaml").is_file()


@pytest.mark.parametrize("name", sorted(MARKED))
def test_paper_scene_gives_the_configs_p_and_p_minus(name):
    cfg = scene_config(name)
    p = decompose(MARKED[name])
    assert p.full == cfg.prompt.replace("{object}", "sphere")
    assert p.minus == cfg.prompt_minus
    assert (p.object_phrase, p.noun, p.materials) == ("a big glass sphere", "sphere", ("glass",))
    assert p.surface == SURFACE[name]
    assert p.text == MARKED[name]


@pytest.mark.parametrize("name", PANO_EXACT)
def test_paper_scene_gives_the_configs_pano_prompt(name):
    assert decompose(MARKED[name]).pano == scene_config(name).pano_prompt


@pytest.mark.parametrize("name", sorted(PANO_DERIVED))
def test_hand_written_pano_prompts_differ_and_can_be_kept(name):
    cfg = scene_config(name)
    p = decompose(MARKED[name])
    assert p.pano == f"{PANO_PREFIX} {PANO_DERIVED[name]}"
    assert p.pano != cfg.pano_prompt
    kept = decompose(MARKED[name], pano=cfg.pano_prompt)
    assert kept.pano == cfg.pano_prompt
    assert (kept.full, kept.minus, kept.surface) == (p.full, p.minus, p.surface)


@pytest.mark.parametrize("name", sorted(MARKED))
@pytest.mark.parametrize("noun", ["fox", "cow", "sculpture"])
def test_with_object_is_the_configs_object_placeholder(name, noun):
    cfg = scene_config(name)
    p = decompose(MARKED[name])
    q = p.with_object(noun)
    assert q.full == cfg.prompt.replace("{object}", noun)
    assert (q.minus, q.pano, q.surface, q.materials) == (p.minus, p.pano, p.surface, p.materials)
    assert (q.noun, q.object_phrase) == (noun, f"a big glass {noun}")
    assert q.text == MARKED[name].replace("glass sphere", f"glass {noun}")
    assert q.with_object("sphere") == p
    # the placeholder itself may be the noun of the marked prompt
    placeholder = decompose(MARKED[name].replace("glass sphere", "glass {object}"))
    assert placeholder.noun == "{object}" and placeholder.full == cfg.prompt
    assert placeholder.with_object(noun) == q


def test_with_object_fixes_an_article_before_the_noun_and_keeps_overrides():
    p = decompose("A kitchen with a marble island, [[with a sphere on top,]] and stools.", minus="M", pano="P")
    q = p.with_object("owl")
    assert q.full == "A kitchen with a marble island, with an owl on top, and stools."
    assert q.object_phrase == "an owl" and (q.minus, q.pano) == ("M", "P")
    assert q.with_object("rubber duck").object_phrase == "a rubber duck"
    # an article before another word stays
    assert decompose(MARKED["cafe"]).with_object("owl").object_phrase == "a big glass owl"
    for bad in ("", "  ", "[[x]]"):
        with pytest.raises(ValueError, match="noun"):
            p.with_object(bad)


def test_prompts_is_frozen():
    p = decompose(MARKED["office"])
    assert isinstance(p, Prompts)
    with pytest.raises(AttributeError):
        p.full = "x"


@pytest.mark.parametrize(
    "text, problem",
    [
        ("A cozy living room with a wooden table, with a big glass sphere on top, and a sofa.", "no object phrase"),
        (
            "A room with a table, [[with a glass sphere on top,]] and [[a glass cube on the floor,]] a sofa.",
            "2 phrases",
        ),
        ("A room with a table, [[with a glass sphere on top, and a sofa.", "unbalanced"),
        ("A room with a table, with a glass sphere on top,]] and a sofa.", "unbalanced"),
        ("A room with a table, ]]with a glass sphere on top,[[ and a sofa.", "unbalanced"),
        ("A room with a table, [[]] and a sofa.", "empty"),
        ("A room with a table, [[ , ]] and a sofa.", "empty"),
    ],
)
def test_malformed_marks_raise_naming_the_key_and_the_form(text, problem):
    with pytest.raises(ValueError) as err:
        decompose(text)
    msg = str(err.value)
    assert problem in msg
    assert repr(text) in msg
    assert "scene.text" in msg
    assert "[[with a big glass sphere on top,]]" in msg


def test_no_object_before_placement_words_raises():
    with pytest.raises(ValueError, match="names no object"):
        decompose("A room with a table, [[with on top,]] and a sofa.")


def test_unknown_placement_needs_explicit_minus_and_surface():
    text = "A garden at dusk, [[a big glass sphere next to the fountain,]] with lanterns."
    with pytest.raises(ValueError, match="scene.prompt_minus"):
        decompose(text)
    with pytest.raises(ValueError, match="scene.surface"):
        decompose(text, minus="A garden at dusk, the fountain alone, with lanterns.")
    p = decompose(text, minus="A garden at dusk, the fountain alone, with lanterns.", surface="stone fountain")
    assert p.object_phrase == "a big glass sphere" and p.noun == "sphere"
    assert p.surface == "stone fountain"
    assert p.pano == f"{PANO_PREFIX} on top of a stone fountain in a garden."


def test_on_top_without_a_support_needs_an_explicit_surface():
    text = "A gallery with white walls, [[with a big glass sphere on top,]] and soft spotlights."
    with pytest.raises(ValueError) as err:
        decompose(text)
    assert "scene.surface" in str(err.value) and repr(text) in str(err.value)
    p = decompose(text, surface="white marble plinth")
    assert p.surface == "white marble plinth"
    assert p.minus == "A gallery with white walls, with its clean, empty top, and soft spotlights."
    assert p.pano == f"{PANO_PREFIX} on top of a white marble plinth in a gallery."


def test_explicit_arguments_override_the_derived_ones():
    p = decompose(MARKED["kitchen"], surface="marble island", minus="M")
    assert (p.surface, p.minus) == ("marble island", "M")
    assert p.pano == scene_config("kitchen").pano_prompt  # the surface enters the derived p³⁶⁰
    assert (
        decompose(MARKED["kitchen"], surface="the island").pano
        == f"{PANO_PREFIX} on top of the island in a modern kitchen."
    )
    assert (
        decompose(MARKED["cave"], surface="sandy floor").pano == f"{PANO_PREFIX} from the sandy floor of a rocky cave."
    )
    with pytest.raises(ValueError, match="scene.surface"):
        decompose(MARKED["kitchen"], surface=" ")


@pytest.mark.parametrize(
    "text, minus, object_phrase, surface, pano",
    [
        (  # on top of <NP>
            "A music room, [[a small crystal swan on top of the grand piano,]] near a window.",
            "A music room, the clean, empty top of the grand piano, near a window.",
            "a small crystal swan",
            "grand piano",
            "on top of the grand piano in a music room.",
        ),
        (  # a placement verb, an indefinite surface, no trailing comma in the mark
            "A workshop with tools, [[a glass cube placed on a wooden stool]], and sawdust.",
            "A workshop with tools, a clean, empty wooden stool, and sawdust.",
            "a glass cube",
            "wooden stool",
            "on top of a wooden stool in a workshop.",
        ),
        (  # a ground other than "ground"
            "A quiet library with tall oak shelves, [[a water droplet resting on the floor,]] and reading lamps.",
            "A quiet library with tall oak shelves, the clean, empty floor in front, and reading lamps.",
            "a water droplet",
            "floor",
            "from the floor of a quiet library.",
        ),
        (  # the phrase opens the prompt: p⁻ capitalised, the scene after it
            "[[A diamond ring on the table,]] in a candle-lit restaurant.",
            "The clean, empty table top, in a candle-lit restaurant.",
            "A diamond ring",
            "table",
            "on top of the table in a candle-lit restaurant.",
        ),
        (  # "on top" finds a plural support with a numeral
            "An office with two wooden desks pushed together, a lamp, [[with a glass sphere on top,]] and chairs.",
            "An office with two wooden desks pushed together, a lamp, with its clean, empty top, and chairs.",
            "a glass sphere",
            "wooden desks",
            "on top of two wooden desks in an office.",
        ),
    ],
)
def test_rules_beyond_the_paper_scenes(text, minus, object_phrase, surface, pano):
    p = decompose(text)
    assert p.full == text.replace("[[", "").replace("]]", "")
    assert (p.minus, p.object_phrase, p.surface, p.pano) == (minus, object_phrase, surface, f"{PANO_PREFIX} {pano}")


def test_materials_and_scene():
    p = decompose("A dim bar with a long counter, [[with a tall flint glass and ice figure on top,]] and neon signs.")
    assert p.materials == ("flint", "glass", "ice")
    assert p.noun == "figure" and p.surface == "long counter" and p.scene == "a dim bar"
    assert decompose(MARKED["cave"]).scene == "a rocky cave"


def test_decompose_docstring_example():
    result = doctest.testmod(rules_module, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


# ---------------------------------------------------------------------------- the LLM path


def test_llm_missing_weights_name_the_key(tmp_path):
    for path in (tmp_path / "missing", tmp_path, None):
        with pytest.raises(WeightsNotFoundError, match="scene.prompt_llm"):
            decompose_with_llm("A room with a table, a glass sphere on top.", model_path=path)
    (tmp_path / "weights.bin").write_bytes(b"")
    with pytest.raises(WeightsNotFoundError, match="scene.prompt_llm"):
        decompose_with_llm("A room with a table, a glass sphere on top.", model_path=tmp_path / "weights.bin")


def plain(name):
    return MARKED[name].replace("[[", "").replace("]]", "")


def test_llm_answer_is_parsed_and_decomposed():
    asked = []

    def generate(instruction):
        asked.append(instruction)
        return f" {MARKED['living_room']}\nPrompt: something else"

    p = decompose_with_llm(plain("living_room"), model_path=None, generate=generate)
    assert p == decompose(MARKED["living_room"])
    assert len(asked) == 1 and asked[0].endswith(f"Prompt: {plain('living_room')}\nMarked:")


def test_llm_may_not_change_the_rest_of_the_prompt():
    # the model paraphrases around the phrase and drops the comma: the phrase is found in the prompt itself
    answer = "Sure! A cave lit by fire, [[a big glass  Sphere on the ground]] with gear."
    p = decompose_with_llm(plain("cave"), model_path=None, generate=lambda _: answer, pano="P")
    assert p.full == plain("cave")
    assert p.minus == scene_config("cave").prompt_minus
    assert p.text == MARKED["cave"] and p.pano == "P"


def test_llm_answers_without_a_usable_mark_raise():
    for answer, what in [("I cannot help with that.", "marked no"), ("[[a glass cube on a shelf,]]", "not part")]:
        with pytest.raises(ValueError, match=what) as err:
            decompose_with_llm(plain("office"), model_path=None, generate=lambda _, a=answer: a)
        assert "scene.prompt_llm" in str(err.value) and "scene.text" in str(err.value)


def test_llm_is_not_asked_for_a_marked_prompt():
    def generate(_):
        raise AssertionError("the model was asked")

    assert decompose_with_llm(MARKED["desert"], model_path=None, generate=generate) == decompose(MARKED["desert"])
    with pytest.raises(ValueError, match="scene.text"):
        decompose_with_llm("A room, [[with a sphere on top,", model_path=None, generate=generate)
