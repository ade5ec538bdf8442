"""The diffusion prior (prior.kind sds): SDS guidance from Stable Diffusion 1.5 with an OpenPose
ControlNet. Pure parts (schedules, cameras, prompts, the skeleton condition) need no weights; the guidance
step takes diffusers modules (glimpse/prior/sds/guidance.py)."""
