"""seagul_control: the one NLP builder (direct transcription), LQR, limited-lookahead MPC, closed-loop evaluation."""
