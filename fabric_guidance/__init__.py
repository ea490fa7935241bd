"""fabric_guidance: directional guidance through a pneumatic fabric suit (Yokoe et al. 2025)."""
