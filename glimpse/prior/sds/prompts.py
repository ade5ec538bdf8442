"""The text an SDS step is conditioned on (GTU_REFERENCE.md 4, "Prompts").

The UNet reads the view-augmented prompt with the person's token: stage 05's prompt template
("a photo of a {token} person, {view} view"), the quality words, and for a zoomed view the part
("head", "upper body", "lower body"). The ControlNet reads the same prompt without the token (it
never learnt it). The negative prompt names the opposite view, so a back view is not pulled
towards a face.
"""

from __future__ import annotations

from dataclasses import dataclass

from glimpse.prior.views import person_token, view_prompt

OPPOSITE_VIEW = {"front": "back", "back": "front"}


@dataclass(frozen=True)
class PromptConfig:
    template: str           # with {token} and {view} (as stage 05's prompt_template)
    front_max_deg: float    # azimuths below this are "front" views (as stage 05's)
    back_min_deg: float     # above this "back"; between the two "side"
    quality: str            # appended after the view ("high quality, 8k uhd, realistic")
    negative: str           # the negative prompt ("two people, low quality, ...")
    part_words: dict[str, str]  # zoomed view kind -> words added after the view ("head": "head")


@dataclass(frozen=True)
class ViewPrompts:
    """The three texts of one SDS view."""

    unet: str        # with the person's token
    controlnet: str  # the same without it
    negative: str


def without_token(text: str, token: str) -> str:
    """``text`` with ``token`` removed and the spaces it leaves closed ("a <person-p0> person" -> "a person")."""
    return " ".join(text.replace(token, "").split()).replace(" ,", ",")


def view_prompts(pid: str, view: str, part: str, config: PromptConfig) -> ViewPrompts:
    """Prompts for person ``pid`` seen from ``view`` (front/side/back); ``part`` is the camera's kind (full,
    canonical, head, upper, lower): the zoomed kinds add their words."""
    words = [view_prompt(config.template, pid, view)]
    if part in config.part_words:
        words.append(config.part_words[part])
    if config.quality:
        words.append(config.quality)
    unet = ", ".join(words)
    controlnet = without_token(unet, person_token(pid))
    negative = config.negative
    if view in OPPOSITE_VIEW:
        negative = f"{negative}, {OPPOSITE_VIEW[view]} view"
    return ViewPrompts(unet, controlnet, negative)
