"""Reading control-loop tags (pv, op, mv, sp) from historian exports."""
