"""The dailies review page: `tween dailies SHOT_ROOT...` serves fills waiting for a decision."""
