"""Affordance stage: where the hand touched each part, handle piece and grasp frame."""
