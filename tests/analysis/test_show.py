"""``qlap show``'s text (:func:`qlap_runtime.analysis.show.format_knowledge`): the reference's
notation, one minus sign throughout."""

from __future__ import annotations

import re

from qlap_runtime.analysis.show import format_knowledge

KNOWLEDGE = {
    "step": 9999, "k": 6,
    "landmarks": {
        "u_x": [{"label": "-0", "source": "initial"},
                {"label": "[-292.655, -272.655]", "source": "dbn"}],
        "h_x": [{"label": "[1.5, 1.6]", "source": "event"}],
        "z_F": [],
    },
    "dbns": [{"id": 3, "brel": 0.93, "entropy": 0.52, "plan": True,
              "label": "⟨{h_x}: u_x→(-inf, -292.655) ⇒ h_x.dot→[-]⟩"}],
    "actions": [{"label": "a(h_x.dot, [-])", "reliability": 0.97, "calls": 237,
                 "sufficiently_reliable": True,
                 "plans": [{"dbn": 3, "dbn_label": "⟨{h_x}: u_x→(-inf, -292.655) ⇒ h_x.dot→[-]⟩",
                            "context_o": [], "rel_o": 0.97}]}],
}


def test_landmarks_and_labels_are_written_with_one_minus_sign():
    text = format_knowledge(KNOWLEDGE)
    assert "  u_x        [\u2212292.655, \u2212272.655]" in text
    assert "  h_x        [1.5, 1.6]" in text
    assert "z_F" not in text                                # nothing learned on it
    assert "a(h\u0307_x, [-])  rel 0.97  calls 237  (sufficiently reliable)" in text
    assert "⟨{h_x}: u_x→(−∞, \u2212292.655) ⇒ h\u0307_x→[-]⟩  brel 0.93  H 0.52" in text
    assert not re.search(r"(?<![\w.])-\.?\d", text)         # no ASCII minus before a number
