"""sequence_player: replays RGB-D sequences (SUN3D, 7-Scenes, TUM, synthetic) as image topics."""
