"""Deployment helpers beyond `lerobot-rollout`: `lerobot-focal-policy-server` (LeRobot's async inference).

Nothing here is imported by the plugin itself: the server needs the ``async`` extra (grpcio), which a plain
``pip install`` of the policy does not bring.
"""
