"""Stage `speech` (condition 4): the phrase to its reaching the wearer (speech_latency)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from .base import Draws, Effect, RunContext, param


@dataclass
class SpeechLatency(Effect):
    """Condition 4's phrase reaches the wearer after synthesis and speaking time: the wearer
    can act once the whole phrase is heard, latency = max(0, N(mean_s, sd_s)) + per_word_s *
    words (one draw per phrase).

    mean_s (s, default 0.4): a cloud text-to-speech service (the paper used Microsoft Azure)
    answers in a few hundred milliseconds: an assumption of that order. sd_s (s, default 0.1):
    assumption. per_word_s (s/word, default 0.35): conversational speech runs at about 150-180
    words per minute (0.33-0.4 s per word); numbers such as "thirty-six" are long words.
    """

    name: ClassVar[str] = 'speech_latency'
    stage: ClassVar[str] = 'speech'
    stochastic: ClassVar[bool] = True

    mean_s: float = param(0.4, 's', lo=0.0)
    sd_s: float = param(0.1, 's', lo=0.0)
    per_word_s: float = param(0.35, 's/word', lo=0.0)

    def start(self, ctx: RunContext) -> None:
        self._draws = Draws(ctx.rng(self.name), 'normal')

    def latency(self, text: str) -> float:
        z = self._draws.next()
        return max(0.0, self.mean_s + self.sd_s * z) + self.per_word_s * len(text.split())
