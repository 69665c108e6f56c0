"""The trace stage: which pixels get which rays, the Embree scenes, the radiance of hits, shadow regions."""
