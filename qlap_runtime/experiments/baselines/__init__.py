"""The baselines of chapter 7: Sarsa(λ) with hashed tile coding, Tile-1 and Tile-10 (§7.4,
Appendix H), and tabular Q-learning on QLAP's or random landmarks (§7.7), after J. Mugan,
*Autonomous Qualitative Learning of Distinctions and Actions in a Developing Agent*, PhD
dissertation, UT Austin, 2010. They learn from the task's reward, practising its trials.
"""
