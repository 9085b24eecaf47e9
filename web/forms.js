// Helpers shared by the page's forms: showing problem+json validation errors next to the field
// their JSON pointer names, and short status messages.

/** Clears every field error of a form (or only the one for `pointer`). */
export function clearFieldErrors(form, pointer) {
  for (const slot of form.querySelectorAll('.field-error')) {
    if (pointer !== undefined && slot.dataset.pointer !== pointer) continue;
    slot.textContent = '';
    slot.closest('.field')?.querySelector('input, select')?.removeAttribute('aria-invalid');
  }
}

/**
 * Shows `[{pointer, detail}]` next to the fields; returns the errors that point at no field of
 * the form (the body as a whole, or keys the form does not show), for a general message.
 */
export function showFieldErrors(form, errors) {
  const unplaced = [];
  for (const { pointer, detail } of errors) {
    const slot = [...form.querySelectorAll('.field-error')]
      .find((s) => s.dataset.pointer === pointer && !s.closest('.field')?.hidden);
    if (!slot) {
      unplaced.push(pointer ? `${pointer}: ${detail}` : detail);
      continue;
    }
    slot.textContent = slot.textContent ? `${slot.textContent}; ${detail}` : detail;
    slot.closest('.field')?.querySelector('input, select')?.setAttribute('aria-invalid', 'true');
  }
  return unplaced;
}

/** Sets a status message; `kind` is '', 'ok' or 'error'. */
export function setMessage(element, text, kind = '') {
  element.textContent = text;
  element.className = `message${kind ? ` message-${kind}` : ''}`;
}

/** The number typed in an input, or null when it is empty or not a number. */
export function numberOf(input) {
  if (input.value.trim() === '') return null;
  const value = Number(input.value);
  return Number.isFinite(value) ? value : null;
}
