//! vk (to be written)
