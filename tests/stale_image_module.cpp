// A stand-in for an image module built for another version of the client's image interface: it exports an
// entry under another name (the unversioned one of the first module), which the client must refuse, not call.
extern "C" const void* loomlight_image_module() { return nullptr; }
